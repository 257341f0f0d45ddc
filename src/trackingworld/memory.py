"""The allocator setting of the command line and the benchmarks: memory the process frees is kept for reuse.

The stages make and drop many large temporary arrays (``[N,T]`` and ``[N,T,3]``: 120 frames at 320x240 hold
257k tracks, 120-370 MB each). glibc's malloc serves every block of 32 MB or more with a fresh ``mmap`` and hands
it back on ``free``, so each such array is paged in, and zeroed by the kernel, again: at 120 frames that was a
tenth of the optimisation's time, at 30 frames (arrays below the threshold, reused from the heap) next to none.
:func:`reuse_freed_memory` tells malloc to serve large blocks from its heap as well and to keep freed memory there
(``mallopt``: no ``mmap`` blocks, a 2 GB trim threshold). The 120-frame video of ``benchmarks/bench_scaling.py``:
optimisation 34.9 -> 31.3 s; the 30-frame windows 7.1 -> 6.9 s (``docs/results.md``, stop 45).

A process-wide setting, so the library does not make it on import: ``trackingworld`` (the CLI) and the benchmarks
call it. ``TRACKINGWORLD_MALLOC=0`` in the environment leaves malloc as it is; it does nothing off glibc."""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys

M_TRIM_THRESHOLD = -1  # glibc's mallopt parameters (malloc.h)
M_MMAP_MAX = -4
TRIM_THRESHOLD = 2**31 - 1  # bytes: free memory at the heap's top kept up to this (mallopt takes an int)


def reuse_freed_memory() -> bool:
    """Set glibc's malloc to keep freed memory for reuse (module docstring). True when it was set; False off
    Linux/glibc or with ``TRACKINGWORLD_MALLOC=0``."""
    if os.environ.get("TRACKINGWORLD_MALLOC", "1") == "0" or not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
        libc.gnu_get_libc_version  # noqa: B018 (only glibc has it: another libc's mallopt may differ)
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(M_MMAP_MAX, 0)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))
