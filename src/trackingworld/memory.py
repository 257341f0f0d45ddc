"""Memory: the allocator setting of the command line and the benchmarks (memory the process frees is kept for
reuse), and the estimate of a run's peak memory that warns before a video too large for this machine.

The stages make and drop many large temporary arrays (``[N,T]`` and ``[N,T,3]``: 120 frames at 320x240 hold
257k tracks, 120-370 MB each). glibc's malloc serves every block of 32 MB or more with a fresh ``mmap`` and hands
it back on ``free``, so each such array is paged in, and zeroed by the kernel, again: at 120 frames that was a
tenth of the optimisation's time, at 30 frames (arrays below the threshold, reused from the heap) next to none.
:func:`reuse_freed_memory` tells malloc to serve large blocks from its heap as well and to keep freed memory there
(``mallopt``: no ``mmap`` blocks, a 2 GB trim threshold). The 120-frame video of ``benchmarks/bench_scaling.py``:
optimisation 34.7 -> 30.8 s; its 30-frame windows 6.8 -> 6.6 s (``docs/results.md``, stop 45).

The price: a freed block is handed back to the system only from the heap's top, so one that a later, larger array
cannot reuse stays resident. On ``trackingworld run`` that raised the peak by 2-4% (2.38 -> 2.44 GB at 120 frames,
2.52-2.57 -> 2.56-2.66 GB at 854x480); a worst case in a ``/tmp`` script (6 GB and 2 GB arrays, the 6 GB freed and
reused in part, then an 8 GB one) peaked at 16.2 GB against 8.2 GB. A process-wide setting, so the library does not
make it on import: ``trackingworld`` (the CLI) and the benchmarks call it. ``TRACKINGWORLD_MALLOC=0`` in the
environment leaves malloc as it is; it does nothing off glibc.

On a long real video what stayed resident grew large: the 2D tracking and the priors make many temporaries, and at
the start of stage 3 of ``../shared/data/pstudio.mp4``'s 150 frames the process held 2.4 GB more than a run on its
cached tracks. :func:`release_freed_memory` (glibc's ``malloc_trim``) hands the pages of every free block back, the
blocks kept for reuse: after the 2D tracking, after the priors and before the stages that hold the peak
(``pipeline.world``: stage 3 and the rigid step). That run, the tracks computed afresh: peak RSS
17,077,720 kB released after the tracking and the priors only, 13,042,048 kB also before the two stages (stop 87,
``docs/speed.md``), the same result to the bit; the optimisation 302 s against 288 s on the cached tracks without
the release (its page faults; released before every stage, 326 s). The 120-frame synthetic video (priors given, two
runs of each, alternated): peak 2,813,256 / 2,582,984 kB before, 2,491,072 / 2,575,696 kB after, the optimisation
36.3 / 34.3 s before, 36.2 / 35.9 s after.

The estimate (:func:`estimate_peak_bytes`): a run holds a few arrays of every track at every frame, so its peak
grows with tracks x frames, and the dense tracks grow with the frames too (the pixels no track covers start new
ones). Peak RSS of ``trackingworld run`` measured at stop 45 (``/usr/bin/time -v``, the `default` scene with its
priors given): 0.86 / 1.38 / 2.44 GB for 124,656 / 164,919 / 257,283 tracks over 30 / 60 / 120 frames at 320x240
(tracks given); 2.56-2.66 GB for 747,489 tracks over 30 frames at 854x480 (with the 2D tracking). BASE_BYTES +
BYTES_PER_ENTRY x tracks x frames lies 4% below to 30% above those. Before the 2D tracking the tracks are
guessed from the pixels and frames (``TRACKS_PER_PIXEL_FRAME`` new tracks per pixel per frame beyond the first
frame's). Real videos start more than the synthetic scenes: ``../shared/data/pstudio.mp4`` (640x360, a fixed camera,
people moving) 632,024 tracks in 40 frames and 1,404,324 in 150, ``dog.mp4`` 1,011,809 in its 32 frames of 854x480:
0.034-0.046 a pixel a frame, against 0.020 for the `default` scene (112k-125k / 160-165k / 257k tracks at 30 / 60 /
120 frames of 320x240, 747k at 30 frames of 854x480). The guess takes 0.04 since stop 87 (it took 0.02, 1.5x below
the real videos): 599,040 / 1,612,800 / 934,617 for those three, 1.4-1.7x above the synthetic ones; it only
decides a warning, and too high is the safer side. A long real video's peak: pstudio's 150 frames (weight-free
priors) peaked at 23.5 GB (22,913,136 kB) at stop 86 with the tracks cached, 15.5 GB after the copies that stop let
go (``docs/speed.md``, "Stop 86"), and since stop 87 (the rigid step reads the dynamic tracks in place, the freed memory
handed back above) 13,042,048 kB with the tracks computed in the run, 24% below the estimate of 17.55 GB;
854x480 2.52-2.64 GB (1-6% above it, stop 86)."""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import os
import sys
from pathlib import Path

M_TRIM_THRESHOLD = -1  # glibc's mallopt parameters (malloc.h)
M_MMAP_MAX = -4
TRIM_THRESHOLD = 2**31 - 1  # bytes: free memory at the heap's top kept up to this (mallopt takes an int)


@functools.cache
def _glibc() -> ctypes.CDLL | None:
    """The C library when it is glibc on Linux (its ``mallopt`` and ``malloc_trim`` are the ones meant here), else
    None; loaded once (``find_library`` asks ``ldconfig``)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.gnu_get_libc_version  # noqa: B018 (only glibc has it: another libc's mallopt may differ)
    except (OSError, AttributeError):
        return None
    libc.mallopt.argtypes, libc.mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    libc.malloc_trim.argtypes, libc.malloc_trim.restype = (ctypes.c_size_t,), ctypes.c_int
    return libc


def reuse_freed_memory() -> bool:
    """Set glibc's malloc to keep freed memory for reuse (module docstring). True when it was set; False off
    Linux/glibc or with ``TRACKINGWORLD_MALLOC=0``."""
    libc = None if os.environ.get("TRACKINGWORLD_MALLOC", "1") == "0" else _glibc()
    if libc is None:
        return False
    return bool(libc.mallopt(M_MMAP_MAX, 0)) and bool(libc.mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))


def release_freed_memory() -> bool:
    """Hand the pages of the memory the process has freed back to the system (glibc's ``malloc_trim``: the heap's
    free blocks anywhere in it, not only at its top), after a phase whose many temporaries leave holes later arrays
    cannot fill (module docstring: after the 2D tracking and the priors, before the stages of the peak). The blocks
    stay the heap's, so a later array that fits one takes it, its pages faulted in again. True when it was called;
    False off Linux/glibc."""
    libc = _glibc()
    if libc is None:
        return False
    libc.malloc_trim(0)
    return True


BASE_BYTES = 0.7e9  # the interpreter, torch, the frames and priors of a short video (module docstring)
BYTES_PER_ENTRY = 80.0  # per track per frame, at the run's peak
TRACKS_PER_PIXEL_FRAME = 0.04  # new tracks per pixel per frame, beyond one per pixel of the first frame (real videos)


def estimate_peak_bytes(n_tracks: int, n_frames: int) -> float:
    """Bytes: the estimated peak memory of ``trackingworld run`` on ``n_tracks`` dense tracks over ``n_frames``
    frames (module docstring)."""
    return BASE_BYTES + BYTES_PER_ENTRY * float(n_tracks) * float(n_frames)


def guess_tracks(height: int, width: int, n_frames: int) -> int:
    """The dense tracks a video of ``n_frames`` frames of ``height`` x ``width`` px is likely to hold (module
    docstring): a guess, before the 2D tracking."""
    return int(height * width * (1 + TRACKS_PER_PIXEL_FRAME * n_frames))


def available_bytes(meminfo: str | Path = "/proc/meminfo", cgroup: str | Path = "/sys/fs/cgroup") -> float | None:
    """Bytes this process can still take: the kernel's MemAvailable (``meminfo``), or less under a container's
    memory limit (``cgroup``: v2 ``memory.max`` less ``memory.current``, or v1 ``memory/memory.limit_in_bytes``
    less ``memory/memory.usage_in_bytes``); None where none of them is known (not Linux)."""
    out = None
    try:
        for line in Path(meminfo).read_text().splitlines():
            if line.startswith("MemAvailable:"):
                out = float(line.split()[1]) * 1024
    except OSError:
        pass
    cg = Path(cgroup)
    for limit_file, usage_file in (("memory.max", "memory.current"),
                                   ("memory/memory.limit_in_bytes", "memory/memory.usage_in_bytes")):
        try:
            limit = (cg / limit_file).read_text().strip()
            if limit == "max" or float(limit) >= 2**60:  # no limit (v1 writes a number near 2^63)
                continue
            left = float(limit) - float((cg / usage_file).read_text())
        except (OSError, ValueError):
            continue
        out = left if out is None else min(out, left)
    return out


def memory_warning(n_tracks: int, n_frames: int, available: float | None = None, guessed: bool = False
                   ) -> str | None:
    """A one-line warning when the estimated peak of a run on ``n_tracks`` tracks (``guessed``: before the 2D
    tracking) over ``n_frames`` frames exceeds ``available`` bytes (None: :func:`available_bytes`); None when it
    fits or the available memory is unknown."""
    available = available_bytes() if available is None else available
    need = estimate_peak_bytes(n_tracks, n_frames)
    if available is None or need <= available:
        return None
    return (f"{'about ' if guessed else ''}{n_tracks:,} tracks x {n_frames} frames need about {need / 1e9:.1f} GB "
            f"at the peak, {available / 1e9:.1f} GB is available: the run may be killed for memory; fewer frames "
            f"(--max-frames, --frame-stride) or pixels (--resize) make it smaller")
