"""Loops over frames, and compiled kernels' items (:func:`in_parts`), run on threads; frames worked out ahead on a
spare thread (:class:`FramesAhead`), and the cores such a thread takes from the splits (:func:`core_taken`).

The video depth's per-frame work is a kNN search (scipy's releases the GIL)
and large numpy array operations (which release it too), so two frames on two cores overlap. Each frame writes its
own slice of the output, so the result does not depend on the number of threads. Threads rather than processes:
the arrays are shared, not copied. Stage 3's followers and the short tracks' vote, run the same way, measured no
faster in a whole run (30 frames at 854x480, two runs each beside stop 49's code; ``docs/speed.md``), and stay
sequential. :func:`set_thread_cap` caps every pool of the process (``trackingworld run --threads``), for runs that
share a machine."""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import cv2
import numpy as np
import torch

from trackingworld import reproducible

MAX_THREADS = 8
_cap: int | None = None  # set_thread_cap's limit for this process (None: every CPU it may run on)
_pool: ThreadPoolExecutor | None = None  # in_parts' threads, made on first use and kept
_pool_lock = threading.Lock()


def cpu_count() -> int:
    """The CPUs this process may run on (its affinity mask where the system has one)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


_taken = 0  # CPUs taken by work on threads of its own (:func:`core_taken`)
_taken_lock = threading.Lock()


def worker_threads(limit: int = MAX_THREADS) -> int:
    """The CPUs this process may run on, at most ``limit`` and at most the cap of :func:`set_thread_cap`, less
    those taken by work beside the caller's (:func:`core_taken`); at least 1."""
    return max(1, min(limit, cpu_count(), _cap or limit) - _taken)


@contextmanager
def core_taken() -> Iterator[None]:
    """:func:`worker_threads` one less inside the block, in every thread: for work on a thread of its own beside
    other work (the carrying of the hidden frames and the video depth's search ahead, beside the rigid step), so
    that neither splits its work into more threads than the cores left to it; with more, the parts wait on each
    other. The 854x480 run on 2 cores (``docs/speed.md``, stop 73), each alternated with stop 72's code: with the
    search beside it and no core taken, the rigid step took 18.5 / 21.2 / 18.3 s against 14.6 / 15.9 / 17.8 s;
    with one taken for the whole step 14.5 / 12.5 / 19.3 s against 18.4 / 17.0 / 19.5 s."""
    global _taken
    with _taken_lock:
        _taken += 1
    try:
        yield
    finally:
        with _taken_lock:
            _taken -= 1


def set_thread_cap(n: int) -> None:
    """Every pool of this process at most ``n`` threads from now on: torch's intra-op threads, OpenCV's and the frame
    loops' (:func:`worker_threads`). For several runs sharing a machine: torch's OpenMP threads busy-wait between
    the many small operations of the rigid step and the fits, and with more threads than cores in all the processes
    together they wait on each other (two runs of the rigid step at once on 2 cores, 2 threads each: 344 s instead
    of 8 s; ``docs/speed.md``, stop 58)."""
    global _cap
    _cap = max(1, int(n))
    torch.set_num_threads(_cap)
    cv2.setNumThreads(_cap)


def each_frame(work: Callable[[int], None], frames: Iterable[int], threads: int | None = None) -> None:
    """``work(t)`` for every frame ``t`` of ``frames``, on ``threads`` threads (None: :func:`worker_threads`; 1:
    in this thread, in order). ``work`` writes its results itself, each frame to its own part of an output; its
    exceptions are raised here."""
    n = worker_threads() if threads is None else max(1, threads)
    if n == 1:
        for t in frames:
            work(t)
        return

    def in_thread(t: int) -> None:  # OpenCV's IPP switch is per thread: this one's set as the caller's block wants
        reproducible.follow()
        work(t)

    with ThreadPoolExecutor(n) as pool:
        for _ in pool.map(in_thread, frames):
            pass


def part_bounds(cost: np.ndarray, parts: int, min_cost: float) -> np.ndarray:
    """``[k+1]`` int: the bounds of at most ``parts`` contiguous parts of ``n`` items of cumulative cost ``cost
    [n+1]`` (``cost[0] = 0``), cut where the cost reaches equal shares, each part costing at least ``min_cost``
    (fewer parts where the whole costs less: one part ``[0, n]``)."""
    n, total = len(cost) - 1, float(cost[-1])
    k = int(max(1, min(parts, total // max(min_cost, 1e-300), n)))
    if k == 1:
        return np.array([0, n], np.int64)
    cuts = np.searchsorted(cost, total * np.arange(1, k) / k)
    return np.unique(np.r_[0, np.clip(cuts, 1, n - 1), n]).astype(np.int64)


def in_parts(work: Callable[[int, int], object], bounds: np.ndarray) -> list:
    """``[work(lo, hi)]`` for each part ``lo, hi`` of ``bounds`` (:func:`part_bounds`), in order, the parts at once:
    the first in this thread, the others on a kept pool of threads. For compiled kernels that release the GIL
    (numba's ``nogil``), each part reading shared inputs and writing only its own items, so that the result is
    the same to the bit as one call over all of them, on any number of threads."""
    global _pool
    parts = [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    if len(parts) == 1:
        return [work(*parts[0])]
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(MAX_THREADS - 1, thread_name_prefix="tw-part")
    rest = [_pool.submit(work, a, b) for a, b in parts[1:]]
    first = work(*parts[0])
    return [first] + [f.result() for f in rest]


_TAKEN = object()  # FramesAhead: a frame its caller took before the spare thread came to it
_FAILED = object()  # ... and one whose work raised there (the caller does it again and meets the error itself)


class FramesAhead:
    """``work(t)`` of ``frames`` done ahead of time, one frame after another, by a spare thread (:meth:`run`), for
    work whose inputs are ready before its caller is (the video depth's kNN search, beside the rigid-mover step).
    Each frame is claimed once: :meth:`take` hands over a frame's result, waiting for it where the thread has the
    frame in hand, and None where the thread never came to it (the caller then does that frame its own way); after
    :meth:`stop` the thread claims no more. ``work`` must give what the caller would have worked out itself, so
    that how many frames were done ahead changes nothing but the time."""

    def __init__(self, work: Callable[[int], object], frames: Iterable[int]):
        self._work = work
        self._todo = list(frames)
        self._next = 0
        self._lock = threading.Lock()
        self._state: dict[int, object] = {}  # frame -> Event while in hand, then its result (or _TAKEN / _FAILED)
        self._stopped = False
        self.done = 0  # frames the spare thread finished

    def _claim(self):
        with self._lock:
            while not self._stopped and self._next < len(self._todo):
                t = self._todo[self._next]
                self._next += 1
                if t not in self._state:
                    self._state[t] = ev = threading.Event()
                    return t, ev
        return None

    def run(self) -> None:
        """Works out the frames no one has claimed, in order, until none is left or :meth:`stop` was called."""
        while (claim := self._claim()) is not None:
            t, ev = claim
            try:
                out = self._work(t)
            except Exception:  # noqa: BLE001 - the caller does the frame again and meets the error itself
                out = _FAILED
            with self._lock:
                self._state[t] = out
                self.done += out is not _FAILED
            ev.set()

    def stop(self) -> None:
        """No frame is claimed from now on (the one in hand is finished)."""
        with self._lock:
            self._stopped = True

    def take(self, t: int):
        """Frame ``t``'s result, once: waited for where the spare thread has it in hand; None where it never came to
        it (or its work raised there)."""
        with self._lock:
            s = self._state.get(t)
            if s is None:
                self._state[t] = _TAKEN
                return None
        if isinstance(s, threading.Event):
            s.wait()
        with self._lock:
            out = self._state[t]
            self._state[t] = _TAKEN
        return None if out is _TAKEN or out is _FAILED else out


@contextmanager
def torch_threads(limit: int) -> Iterator[None]:
    """torch's intra-op threads at most ``limit`` inside the block (restored after it). For work made of many
    small tensor operations, where more threads cost more in handing out the work than they save."""
    old = torch.get_num_threads()
    torch.set_num_threads(max(1, min(old, limit)))
    try:
        yield
    finally:
        torch.set_num_threads(old)
