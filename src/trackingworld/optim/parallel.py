"""Loops over frames run on threads. The video depth's per-frame work is a kNN search (scipy's releases the GIL)
and large numpy array operations (which release it too), so two frames on two cores overlap. Each frame writes its
own slice of the output, so the result does not depend on the number of threads. Threads rather than processes:
the arrays are shared, not copied. Stage 3's followers and the short tracks' vote, run the same way, measured no
faster in a whole run (30 frames at 854x480, two runs each beside stop 49's code; ``docs/speed.md``), and stay
sequential."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import torch

MAX_THREADS = 8


def worker_threads(limit: int = MAX_THREADS) -> int:
    """The CPUs this process may run on, at most ``limit``."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(limit, cpus))


def each_frame(work: Callable[[int], None], frames: Iterable[int], threads: int | None = None) -> None:
    """``work(t)`` for every frame ``t`` of ``frames``, on ``threads`` threads (None: :func:`worker_threads`; 1:
    in this thread, in order). ``work`` writes its results itself, each frame to its own part of an output; its
    exceptions are raised here."""
    n = worker_threads() if threads is None else max(1, threads)
    if n == 1:
        for t in frames:
            work(t)
        return
    with ThreadPoolExecutor(n) as pool:
        for _ in pool.map(work, frames):
            pass


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
