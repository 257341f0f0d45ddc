"""Reproducible optimisation: OpenCV's IPP code paths off while the world-centric lifting runs, so that one input
(frames, tracks, priors) gives one result to the bit.

OpenCV hands some of its functions to Intel's IPP (its ``GaussianBlur`` and ``Sobel`` on float32 images among them),
and IPP's results depend on where the arrays lie in memory: the same call on the same values can differ in the last
bit from one call to the next. In the edge-aware prior of the depth fields (``optim.edge_prior``) 16-23 of the 2.5M
pixels of `default` 0 came out different from the first call's in each of six more calls, by up to 1.4e-6 in log
depth (on one thread: 34 pixels in four calls of five); without IPP none did. The label tests and the rigid-mover
step carry such bits on: two runs of `default` 0 from the same tracks wrote ``tracks_3d`` different in 962 entries
(up to 1.9e-6 m) and ``depth`` in 150 (``docs/results.md``, stop 74).

The 2D tracker keeps IPP: with it off everywhere, twelve scenes tracked again came out 0.29 points lower in world 3D
accuracy on the mean and their ATE a little higher (stop 74), so the tracks' last bits are left as OpenCV makes them.
IPP is off only inside :func:`ipp_off`, which ``pipeline.run`` holds around the lifting. OpenCV keeps the switch
(``cv2.ipp.setUseIPP``) per thread: the block sets it in the calling thread, and the frame loops' threads
(``optim.parallel.each_frame``) take it from :func:`follow` before each frame. ``TRACKINGWORLD_IPP=1`` in the
environment leaves IPP on.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager

import cv2

_off = threading.Event()  # set while a lifting runs with IPP off (the worker threads read it in follow)


def wanted() -> bool:
    """Whether the lifting turns IPP off (not with ``TRACKINGWORLD_IPP=1``)."""
    return os.environ.get("TRACKINGWORLD_IPP") != "1"


@contextmanager
def ipp_off() -> Iterator[None]:
    """OpenCV's IPP off in this thread, and in the frame loops' threads (:func:`follow`), until the block ends;
    then as it was. Nothing with ``TRACKINGWORLD_IPP=1``."""
    if not wanted():
        yield
        return
    was = cv2.ipp.useIPP()
    cv2.ipp.setUseIPP(False)
    _off.set()
    try:
        yield
    finally:
        _off.clear()
        cv2.ipp.setUseIPP(was)


def follow() -> None:
    """In a worker thread: OpenCV's IPP as the block of :func:`ipp_off` wants it (off inside one, OpenCV's own
    setting outside: a kept thread may have served a block before)."""
    cv2.ipp.setUseIPP(not _off.is_set())


# the libraries whose numbers a result carries: torch, and every package `make setup` pins in constraints.txt
ENVIRONMENT_PACKAGES = ("numpy", "scipy", "torch", "opencv-contrib-python-headless", "numba", "llvmlite", "av",
                        "pyamg")


# the vector extensions whose presence changes the code paths OpenCV (IPP), numpy and torch dispatch to, and so
# their last bits: one input, one code and one set of libraries gave other last digits on two machines (stop 78)
SIMD_FLAGS = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512bw", "avx512vl", "avx512_vnni", "avx512_bf16",
              "amx_tile")


def cpu_info(cpuinfo: str = "/proc/cpuinfo") -> dict:
    """``{"model": str | None, "simd": [flags]}``: the CPU's model name and which of :data:`SIMD_FLAGS` it has, read
    from ``cpuinfo`` (Linux); the platform's processor string and no flags elsewhere."""
    import platform

    try:
        with open(cpuinfo) as f:
            text = f.read()
    except OSError:
        return {"model": platform.processor() or None, "simd": []}
    model, flags = None, set()
    for line in text.splitlines():
        key, _, value = line.partition(":")
        key = key.strip()
        if key == "model name" and model is None:
            model = value.strip()
        elif key == "flags" and not flags:
            flags = set(value.split())
    return {"model": model, "simd": [f for f in SIMD_FLAGS if f in flags]}


def environment() -> dict:
    """What made a result besides its input and settings: the Python, the platform, and the versions of the
    libraries whose numbers it carries (OpenCV's flow and filters, torch's solvers, numba's kernels, PyAV's decoding,
    pyamg's solve), written as ``DIR/environment.json`` by ``pipeline.run``. ``make setup`` pins them
    (``constraints.txt``), but a plain ``pip install`` takes ``pyproject.toml``'s ranges, so one input tracked on
    another machine can give other last digits; this says which libraries to compare."""
    import platform
    from importlib import metadata

    from trackingworld import __version__

    versions = {}
    for name in ENVIRONMENT_PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return {"trackingworld": __version__, "python": platform.python_version(), "platform": platform.platform(),
            "cpus": os.cpu_count(), "cpu": cpu_info(), "cv2": cv2.__version__, "cv2_threads": cv2.getNumThreads(),
            "ipp": cv2.ipp.getIppVersion(),
            "ipp_in_tracking": bool(cv2.ipp.useIPP()), "ipp_off_in_lifting": wanted(), "packages": versions}
