"""Reproducible runs: OpenCV without its IPP code paths, so that one input gives one result to the bit.

OpenCV hands some of its functions to Intel's IPP (its ``GaussianBlur`` and ``Sobel`` on float32 images among them),
and IPP's results depend on where the arrays lie in memory: the same call on the same values can differ in the last
bit from one call to the next. In the edge-aware prior of the depth fields (``optim.edge_prior``) 16-23 of the 2.5M
pixels of `default` 0 came out different from the first call's in each of six more calls, by up to 1.4e-6 in log
depth (on one thread: 34 pixels in four calls of five); without IPP none did. The label tests and the rigid-mover
step carry such bits on: two runs of `default` 0 from the same tracks wrote ``tracks_3d`` different in 962 entries
(up to 1.9e-6 m) and ``depth`` in 150; with IPP off, two runs wrote the same ``result.npz`` to the bit
(``docs/results.md``, stop 74). The price in time is measured there too.

OpenCV reads ``OPENCV_IPP`` once, when ``cv2`` is first imported, and its run-time switch
(``cv2.ipp.setUseIPP``) holds for the calling thread alone, not for OpenCV's own worker threads nor the
pipeline's. So this is a process-wide setting made before the first import of ``cv2``, and the library does not
make it on import: ``trackingworld`` (the CLI), the demo and the benchmarks call :func:`without_ipp` first, and a
batch's worker processes inherit it (:func:`quiet_children`). ``TRACKINGWORLD_IPP=1`` in the environment leaves IPP
as OpenCV has it.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager

QUIET = "ERROR"  # OpenCV's log level while it starts: it warns on one line that OPENCV_IPP turned IPP off
CHILD_LOG_LEVEL = "TRACKINGWORLD_OPENCV_LOG_LEVEL"  # the level asked for, handed to a batch's workers


def without_ipp() -> bool:
    """Turn OpenCV's IPP off for this process and the processes it starts (module docstring). True when IPP is off
    in every thread from now on; False with ``TRACKINGWORLD_IPP=1``, where OpenCV was built without IPP, or when
    ``cv2`` was imported before this call (then nothing changes)."""
    if os.environ.get("TRACKINGWORLD_IPP") == "1":
        return False
    if "cv2" in sys.modules:  # too late: OpenCV's worker threads and the processes started keep IPP, and one
        return False  # thread without it would give results neither a run with IPP nor one without gives
    os.environ["OPENCV_IPP"] = "disabled"
    with _quiet_start():
        import cv2

        return not cv2.ipp.useIPP()  # OpenCV reads OPENCV_IPP, and warns, at this first question


@contextmanager
def _quiet_start() -> Iterator[None]:
    """OpenCV's start-up warning about ``OPENCV_IPP`` left out: its log level lowered in the environment while
    ``cv2`` is imported and first asked about IPP, then set back to what the environment asked for (OpenCV's
    default, warnings, if nothing)."""
    asked = os.environ.get("OPENCV_LOG_LEVEL")
    os.environ["OPENCV_LOG_LEVEL"] = QUIET
    try:
        yield
    finally:
        if asked is None:
            del os.environ["OPENCV_LOG_LEVEL"]
        else:
            os.environ["OPENCV_LOG_LEVEL"] = asked
    restore_log_level(asked)


def restore_log_level(asked: str | None = None) -> None:
    """OpenCV's log level as ``OPENCV_LOG_LEVEL`` names it (``asked``; OpenCV's own default, warnings, for None or
    a name it does not know)."""
    import cv2

    levels = {"SILENT": cv2.utils.logging.LOG_LEVEL_SILENT, "FATAL": cv2.utils.logging.LOG_LEVEL_FATAL,
              "ERROR": cv2.utils.logging.LOG_LEVEL_ERROR, "WARNING": cv2.utils.logging.LOG_LEVEL_WARNING,
              "INFO": cv2.utils.logging.LOG_LEVEL_INFO, "DEBUG": cv2.utils.logging.LOG_LEVEL_DEBUG,
              "VERBOSE": cv2.utils.logging.LOG_LEVEL_VERBOSE}
    cv2.utils.logging.setLogLevel(levels.get((asked or "WARNING").upper(), cv2.utils.logging.LOG_LEVEL_WARNING))


@contextmanager
def quiet_children() -> Iterator[None]:
    """Processes started inside this block (a batch's ``--jobs`` workers) start OpenCV without its warning about
    ``OPENCV_IPP``, which they inherit; each worker sets its log level back (:func:`restore_log_level`) in its
    initialiser (:func:`worker_started`). Does nothing while IPP is on."""
    if os.environ.get("OPENCV_IPP") != "disabled":
        yield
        return
    asked = os.environ.get("OPENCV_LOG_LEVEL")
    os.environ["OPENCV_LOG_LEVEL"] = QUIET
    os.environ[CHILD_LOG_LEVEL] = asked or ""  # for worker_started
    try:
        yield
    finally:
        del os.environ[CHILD_LOG_LEVEL]
        if asked is None:
            del os.environ["OPENCV_LOG_LEVEL"]
        else:
            os.environ["OPENCV_LOG_LEVEL"] = asked


def worker_started() -> None:
    """In a process started inside :func:`quiet_children`: OpenCV asked about IPP once (it reads ``OPENCV_IPP``,
    and would warn, at that first question), then its log level set back to the parent's."""
    if CHILD_LOG_LEVEL not in os.environ:
        return
    import cv2

    cv2.ipp.useIPP()
    restore_log_level(os.environ[CHILD_LOG_LEVEL] or None)
