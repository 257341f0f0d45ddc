"""Reading a dense result at arbitrary ground-truth query points.

A result holds its own tracks, not the benchmark's queries. For each query (t, x, y) we take the k
result tracks visible at frame t nearest to (x, y) (within ``radius`` px) and combine them with
inverse-distance weights: 2D positions keep the query's offset from its neighbours, 3D positions and
visibility are weighted means. This is the sampling a dense method's output needs to be compared with a
sparse benchmark; it never uses ground truth beyond the query itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


@dataclass
class Matched:
    uv: np.ndarray  # [N,T,2] pixels
    xyz: np.ndarray  # [N,T,3] world
    visible: np.ndarray  # [N,T] bool
    is_dynamic: np.ndarray  # [N] bool
    found: np.ndarray  # [N] bool: a track was within radius at the query frame


def match_queries(tracks_2d, visible, tracks_3d, is_dynamic, query_frame_gt, query_uv_gt,
                  k: int = 4, radius: float = 4.0) -> Matched:
    N = len(query_frame_gt)
    T = visible.shape[1]
    uv = np.zeros((N, T, 2), np.float64)
    xyz = np.zeros((N, T, 3), np.float64)
    vis = np.zeros((N, T), bool)
    dyn = np.zeros(N, bool)
    found = np.zeros(N, bool)
    for t in np.unique(query_frame_gt):
        sel = np.flatnonzero(query_frame_gt == t)
        cand = np.flatnonzero(visible[:, t])
        if cand.size == 0:
            cand = np.arange(tracks_2d.shape[0])
        tree = cKDTree(tracks_2d[cand, t])
        kk = min(k, cand.size)
        d, j = tree.query(query_uv_gt[sel], k=kk)
        d, j = d.reshape(len(sel), kk), j.reshape(len(sel), kk)
        idx = cand[j]  # [n,k]
        w = 1.0 / (d + 1e-3)
        w /= w.sum(1, keepdims=True)
        offs = query_uv_gt[sel][:, None, None, :] - tracks_2d[idx, t][:, :, None, :]  # [n,k,1,2]
        uv[sel] = (w[..., None, None] * (tracks_2d[idx] + offs)).sum(1)
        xyz[sel] = (w[..., None, None] * tracks_3d[idx]).sum(1)
        vis[sel] = (w[..., None] * visible[idx]).sum(1) > 0.5
        vis[sel, t] = True
        dyn[sel] = (w * is_dynamic[idx]).sum(1) > 0.5
        found[sel] = d[:, 0] <= radius
    return Matched(uv, xyz, vis, dyn, found)
