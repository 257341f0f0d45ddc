"""Static tracks that slip: where a dense 2D track holds its point and where it was dragged off it.

A static point beside a mover is often tracked well from its query frame on and then dragged along by the mover
(the flow of the mover's edge leaks into it): the as-static test over all its frames fails and it would be
called dynamic, its world positions following the mover. The run test looks at the frames around the query
frame only: a static point fitted there (poses held) and the run of consecutive visible frames around the query
frame where that point reprojects within a few pixels. A long run is a static point the tracker lost; a mover's
run is short (it leaves any static point within a few frames). These functions are the run's array logic; the
fit is :func:`trackingworld.optim.static_tests.slip_runs`.
"""

from __future__ import annotations

import numpy as np


def frames_around(vis: np.ndarray, query_frame: np.ndarray, w: int) -> np.ndarray:
    """``[n,T]`` bool: of each track's visible frames ``vis [n,T]``, its query frame ``query_frame [n]`` and the
    ``w`` visible frames nearest it on either side (fewer at the ends of the track)."""
    n, T = vis.shape
    rank = np.cumsum(vis, axis=1, dtype=np.int64)  # visible frames up to and including t
    at_q = rank[np.arange(n), query_frame] - vis[np.arange(n), query_frame]  # visible frames before q
    return vis & (rank - 1 >= at_q[:, None] - w) & (rank - 1 <= at_q[:, None] + w)


def run_around(vis: np.ndarray, bad: np.ndarray, query_frame: np.ndarray) -> np.ndarray:
    """``[n,T]`` bool: the visible frames (``vis [n,T]``) of the run around each query frame (``query_frame [n]``)
    that no ``bad`` frame ``[n,T]`` interrupts: between the last bad visible frame before the query frame and the
    first one after it, exclusive. Empty where the query frame is bad or not visible."""
    n, T = vis.shape
    t = np.arange(T)[None]
    q = query_frame[:, None]
    bad = bad & vis
    before = np.where(bad & (t < q), t, -1).max(1, initial=-1)
    after = np.where(bad & (t > q), t, T).min(1, initial=T)
    run = vis & (t > before[:, None]) & (t < after[:, None])
    broken = bad[np.arange(n), query_frame] | ~vis[np.arange(n), query_frame]
    run[broken] = False
    return run


def long_runs(run: np.ndarray, vis: np.ndarray, frac: float, min_frames: int = 3) -> np.ndarray:
    """``[n]`` bool: runs (``run [n,T]``) of at least ``frac`` of the track's visible frames (``vis [n,T]``) and
    at least ``min_frames``."""
    length = run.sum(1)
    return (length >= min_frames) & (length >= frac * vis.sum(1))
