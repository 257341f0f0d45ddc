"""Where a dynamic track is not visible: carried by the motion of its neighbours on the same object.

Stage 3 places a dynamic track only where it is observed. Holding its last position through the frames it is
hidden (lost by the tracker, occluded, outside the image) leaves it behind while its object moves on.

Carrying: for a hidden frame t of track i, with s its nearest visible frame,
``x_i(t) = x_i(s) + sum_j w_j (x_j(t) - x_j(s)) / sum_j w_j`` over those of its k nearest tracks at frame s
(3D, among the tracks visible at s) that are visible at t too, weights 1 / (distance + 1 cm). A rigid
object's translation is carried exactly, its rotation to first order in the neighbours' spread. A frame with
no such neighbour keeps the held position ``x_i(s)``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from trackingworld.tracking2d.base import nearest_visible_frame


def carry_hidden(xyz: np.ndarray, vis: np.ndarray, k: int = 16, chunk: int = 1 << 16) -> np.ndarray:
    """Tracks ``xyz [N,T,3]`` (world metres; only the visible frames ``vis [N,T]`` are read) with every hidden
    frame carried by the neighbours' motion (module docstring). Tracks never visible are returned as given.
    Returns a new ``[N,T,3]`` array."""
    N, T = vis.shape
    src = nearest_visible_frame(vis)
    out = np.take_along_axis(xyz, src[..., None], axis=1)  # held at the nearest visible frame, carried below
    hi, ht = np.nonzero(~vis & vis.any(1, keepdims=True))  # hidden observations, track-major, frames ascending
    if len(hi) == 0:
        return out
    hs = src[hi, ht]
    # one neighbour pool per (track, anchor frame); the anchor never decreases along a track's frames, so the
    # keys come sorted and their runs are the pairs
    key = hi * T + hs
    new = np.r_[True, key[1:] != key[:-1]]
    inv = np.cumsum(new) - 1
    pair = key[new]
    # each pool: the k nearest tracks visible at the anchor
    pi, ps = pair // T, pair % T
    pool = np.full((len(pair), k), -1, np.int64)
    dist = np.zeros((len(pair), k))
    for s in np.unique(ps):
        who = np.flatnonzero(ps == s)
        cand = np.flatnonzero(vis[:, s])
        kk = min(k + 1, len(cand))
        if kk < 2:
            continue
        d, j = cKDTree(xyz[cand, s]).query(xyz[pi[who], s], k=kk, workers=-1)
        j = cand[j.reshape(len(who), kk)]
        d = d.reshape(len(who), kk)
        # the nearest is the track itself (distance 0): drop the first column
        pool[who, : kk - 1] = j[:, 1:]
        dist[who, : kk - 1] = d[:, 1:]
    wpool = np.where(pool >= 0, 1.0 / (dist + 0.01), 0.0)
    pool = np.maximum(pool, 0) * T  # flat index of (neighbour, frame 0); a missing neighbour has weight 0
    flat = xyz.reshape(N * T, 3)
    visf = vis.reshape(N * T)
    for a in range(0, len(hi), chunk):
        b = slice(a, a + chunk)
        p = inv[b]
        base = pool[p]
        jt = base + ht[b][:, None]  # [c,k] flat index of (neighbour, t)
        js = base + hs[b][:, None]  # ... and of (neighbour, s)
        w = wpool[p] * visf[jt]
        wsum = w.sum(1)
        moved = wsum > 0
        disp = np.einsum("ck,ckd->cd", w[moved], flat[jt[moved]] - flat[js[moved]])
        out[hi[b][moved], ht[b][moved]] += disp / wsum[moved, None]
    return out
