"""The speed-up and the video depth of the appendix: choose the static tracks to optimise, and spread
what the optimised tracks learnt (a local depth scale) to every other track and every pixel.

Both use one mechanism, the appendix's propagation of a local scale ratio ``r = z_optimised / z_prior``:
the k nearest reference tracks in the image plane, weighted by inverse distance between the points lifted
with the raw prior (so that neighbours across a depth edge count little). Rebuilding a dense static track as
its own pixel ray at the propagated depth keeps it exactly on its pixel at the query frame, where averaging
the neighbours' 3D positions (the authors' rebuild) would blur detail below the downsampling cell.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from trackingworld.geometry import unproject
from trackingworld.optim.parallel import each_frame


def cell_representatives(queries: np.ndarray, cell: int) -> np.ndarray:
    """Indices of one track per (query frame, round(x / cell), round(y / cell)) key (the first one).
    queries [N,3] (t, x, y). ``cell <= 1`` keeps every track."""
    if cell <= 1:
        return np.arange(len(queries))
    key = np.stack([queries[:, 0], np.round(queries[:, 1] / cell), np.round(queries[:, 2] / cell)], 1)
    key = key.astype(np.int64)
    if not len(key):
        return np.zeros(0, np.int64)
    # the rows as one int64 each, in the rows' lexicographic order: np.unique of a 1-D array instead of its
    # row-wise sort (the same first indices; 747,490 random queries: 1.13 -> 0.16 s, measured beside another run)
    key -= key.min(0)
    span = key.max(0) + 1
    if float(span[0]) * float(span[1]) * float(span[2]) >= 2.0**62:
        _, first = np.unique(key, axis=0, return_index=True)
    else:
        _, first = np.unique((key[:, 0] * span[1] + key[:, 1]) * span[2] + key[:, 2], return_index=True)
    return np.sort(first)


def cell_cap_mask(uv: np.ndarray, vis: np.ndarray, query_frame: np.ndarray, cell: float, cap: int = 1) -> np.ndarray:
    """Observations ``[N,T]`` bool kept so that every (frame, floor(xy / cell)) cell keeps ``cap`` of the tracks
    visible there: those nearest their own query frame in time (the least drift), then the longest, then the
    lower index. uv [N,T,2] px, vis [N,T], query_frame [N]; ``cap <= 0`` or ``cell <= 0`` (no downsampling)
    keeps all.

    Why: one track per (query frame, cell) bounds the tracks born in a frame but not the tracks seen in it; in a
    longer video more query frames add tracks and each is visible longer, so the observations of the optimised
    tracks grow with the square of the length. Capping them per frame and cell keeps their number
    proportional to the length and leaves every visited cell of every frame observed. Preferring the track
    nearest its query frame measured better than preferring the longest (benchmarks/bench_scaling.py, README).
    """
    if cap <= 0 or cell <= 0 or len(uv) == 0:
        return vis.copy()
    n, t = np.nonzero(vis)
    c = np.floor(uv[n, t] / cell).astype(np.int64)
    c -= c.min(0)
    span = c.max(0) + 1
    key = (t * span[1] + c[:, 1]) * span[0] + c[:, 0]
    order = np.lexsort((n, -vis.sum(1)[n], np.abs(t - query_frame[n]), key))
    ks = key[order]
    start = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    rank = np.arange(len(ks)) - np.repeat(start, np.diff(np.r_[start, len(ks)]))
    sel = order[rank < cap]
    out = np.zeros_like(vis)
    out[n[sel], t[sel]] = True
    return out


def propagate_ratio(ref_uv: np.ndarray, ref_depth: np.ndarray, ref_ratio: np.ndarray, query_uv: np.ndarray,
                    query_depth: np.ndarray, K: np.ndarray, k: int = 4, eps: float = 1e-3,
                    ref_colour: np.ndarray | None = None, query_colour: np.ndarray | None = None,
                    colour_sigma: float = 0.0, idx: np.ndarray | None = None) -> np.ndarray:
    """Inverse-distance-weighted ratio ``[Q]`` at query pixels of one frame.

    ref_uv [R,2] px, ref_depth [R] prior metres, ref_ratio [R]; query_uv [Q,2], query_depth [Q]. Neighbours
    are the k nearest references in the image, weights 1 / (3D distance of the prior-lifted points + eps).
    With ``colour_sigma`` > 0 and both colours given the weights are also multiplied by ``exp(-dc^2 / (2
    sigma^2))``, dc the largest RGB difference (grey levels) between ``query_colour [Q,3]`` and ``ref_colour
    [R,3]``: a joint-bilateral weight, for where the prior-lifted distance cannot tell the two sides of an edge
    apart (its blur). ``idx [Q,k]``: the neighbours' indices when already searched (:func:`nearest_references`).
    """
    if len(ref_uv) == 0:
        return np.ones(len(query_uv))
    k = min(k, len(ref_uv))
    idx = nearest_references(ref_uv, query_uv, k, -1) if idx is None else idx.astype(np.int64, copy=False)
    P = unproject(query_uv, query_depth, K)
    Q = unproject(ref_uv, ref_depth, K)
    colour = colour_sigma > 0 and ref_colour is not None and query_colour is not None
    if not colour and k < 8 and P.dtype == Q.dtype == np.float64:  # numpy's sums of 8 or more run pairwise
        return _idw(P, Q, idx, np.ascontiguousarray(ref_ratio, np.float64), float(eps))
    d = np.linalg.norm(P[:, None] - Q[idx], axis=-1)
    w = 1.0 / (d + eps)
    if colour:
        dc = np.abs(query_colour[:, None].astype(np.float32) - ref_colour[idx].astype(np.float32)).max(-1)
        w = w * np.exp(-0.5 * (dc / colour_sigma) ** 2) + 1e-12  # every weight tiny: the plain mean
    return (w * ref_ratio[idx]).sum(1) / w.sum(1)


def nearest_references(ref_uv: np.ndarray, query_uv: np.ndarray, k: int, workers: int = -1) -> np.ndarray:
    """``[Q,k]`` int64: the indices of the ``k`` (at most ``len(ref_uv)``) references ``ref_uv [R,2]`` px nearest each
    of ``query_uv [Q,2]`` px in the image, nearest first (scipy's kNN on ``workers`` threads: the same on any)."""
    k = min(k, len(ref_uv))
    _, idx = cKDTree(ref_uv).query(query_uv, k=k, workers=workers)
    return idx.reshape(len(query_uv), k)


def pixel_grid(h: int, w: int) -> np.ndarray:
    """``[h*w,2]`` float64 (x, y) of every pixel of an ``h x w`` image, row by row."""
    ys, xs = np.mgrid[0:h, 0:w]
    return np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float64)


@njit(cache=True, error_model="numpy")
def _idw(P, Q, idx, ratio, eps):
    """:func:`propagate_ratio`'s weighted mean without colours, float64, in one pass: the same numbers as numpy's
    ``norm(P[:, None] - Q[idx])``, ``1 / (d + eps)`` and the two sums over the neighbours (the same operations in
    the same order, to the last bit for k < 8, where numpy sums the neighbours one after the other:
    ``tests/test_densify.py``), without the ``[Q,k,3]`` temporaries (a frame of 854x480 pixels, k = 4: 0.22 ->
    0.01 s). P [Q,3], Q [R,3] the lifted points, idx [Q,k], ratio [R] float64."""
    n, k = idx.shape
    out = np.empty(n)
    for i in range(n):
        sw = 0.0
        swr = 0.0
        for j in range(k):
            r = idx[i, j]
            a = P[i, 0] - Q[r, 0]
            b = P[i, 1] - Q[r, 1]
            c = P[i, 2] - Q[r, 2]
            w = 1.0 / (math.sqrt(a * a + b * b + c * c) + eps)
            if j == 0:
                sw = w
                swr = w * ratio[r]
            else:
                sw += w
                swr += w * ratio[r]
        out[i] = swr / sw
    return out


def thin_references(uv: np.ndarray, cell: float) -> np.ndarray:
    """Indices keeping one reference per ``cell`` px square (the first one; fewer, evenly spread references)."""
    if cell <= 1 or len(uv) == 0:
        return np.arange(len(uv))
    c = np.floor(uv / cell).astype(np.int64)
    c -= c.min(0)
    nx = c[:, 0].max() + 1
    key = c[:, 1] * nx + c[:, 0]
    # the first index in each cell, in cell order (np.unique's return_index, without its sort: the same array)
    first = np.full(int(key.max()) + 1, len(uv), np.int64)
    first[key[::-1]] = np.arange(len(uv) - 1, -1, -1)  # written last = the smallest index
    return first[first < len(uv)]


def thinned_observations(uv: np.ndarray, vis: np.ndarray, cell: float,
                         member: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Visible observations of tracks ``uv [N,T,2]`` / ``vis [N,T]`` thinned to one per ``cell`` px square of
    each frame: (track [R], frame [R]) index arrays in frame order. What the video depth needs of a dense set
    of tracks, whose visible observations grow faster than the frames times the pixels. ``member`` [N] bool:
    of those tracks only (the same as passing them copied out, in the same order, without the copy). Compiled for
    float pixels and ``cell`` > 1 (:func:`_thin_kernel`: the same observations as :func:`thinned_observations_numpy`,
    the reference; 747,490 random tracks x 30 frames, cell 4 px: 1.2-1.9 -> 0.5-0.8 s a call, measured beside
    another run)."""
    if cell > 1 and uv.dtype in (np.float32, np.float64):
        keep = np.ones(len(vis), bool) if member is None else np.asarray(member, bool)
        return _thin_kernel(uv, vis, keep, uv.dtype.type(cell))
    return thinned_observations_numpy(uv, vis, cell, member)


def thinned_observations_numpy(uv: np.ndarray, vis: np.ndarray, cell: float,
                               member: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`thinned_observations` in numpy, frame by frame (the reference of :func:`_thin_kernel`)."""
    n_out, t_out = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    vis_t = np.ascontiguousarray(vis.T)  # [T,N]: a frame's flags in one contiguous read
    if member is not None:
        vis_t = vis_t & member[None]
    for t in range(vis.shape[1]):
        v = np.flatnonzero(vis_t[t])
        v = v[thin_references(uv[v, t], cell)]
        n_out.append(v)
        t_out.append(np.full(len(v), t))
    return np.concatenate(n_out), np.concatenate(t_out)


@njit(cache=True, error_model="numpy", nogil=True)
def _thin_kernel(uv, vis, member, cell):
    """:func:`thinned_observations` in two passes over the tracks in their memory order: each visible member's cell
    ``floor(uv / cell)`` in the pixels' precision (``cell`` of uv's dtype, as numpy divides them), the smallest
    track index of each occupied cell of each frame, the cells in row-major order. uv [N,T,2], vis [N,T], member
    [N] bool."""
    N, T = vis.shape
    big = np.iinfo(np.int64).max
    x0 = np.full(T, big, np.int64)
    y0 = np.full(T, big, np.int64)
    x1 = np.full(T, -big, np.int64)
    y1 = np.full(T, -big, np.int64)
    for n in range(N):  # each frame's range of cells
        if not member[n]:
            continue
        for t in range(T):
            if vis[n, t]:
                cx = math.floor(uv[n, t, 0] / cell)
                cy = math.floor(uv[n, t, 1] / cell)
                x0[t], x1[t] = min(x0[t], cx), max(x1[t], cx)
                y0[t], y1[t] = min(y0[t], cy), max(y1[t], cy)
    nx = np.where(x1 >= x0, x1 - x0 + 1, 0)
    start = np.zeros(T + 1, np.int64)
    for t in range(T):
        start[t + 1] = start[t] + (nx[t] * (y1[t] - y0[t] + 1) if nx[t] > 0 else 0)
    first = np.full(start[T], -1, np.int64)
    for n in range(N):  # the tracks in index order: the first to reach a cell is its smallest index
        if not member[n]:
            continue
        for t in range(T):
            if vis[n, t]:
                key = start[t] + (math.floor(uv[n, t, 1] / cell) - y0[t]) * nx[t] + (math.floor(uv[n, t, 0] / cell)
                                                                                      - x0[t])
                if first[key] < 0:
                    first[key] = n
    r = 0
    for k in range(len(first)):
        if first[k] >= 0:
            r += 1
    out_n = np.empty(r, np.int64)
    out_t = np.empty(r, np.int64)
    r = 0
    for t in range(T):  # frame by frame, each frame's cells in row-major order
        for k in range(start[t], start[t + 1]):
            if first[k] >= 0:
                out_n[r] = first[k]
                out_t[r] = t
                r += 1
    return out_n, out_t


def ratio_maps(frame: np.ndarray, ref_uv: np.ndarray, ref_depth: np.ndarray, ref_ratio: np.ndarray,
               prior: np.ndarray, K: np.ndarray, k: int = 4, threads: int | None = None,
               neighbours: Callable[[int], np.ndarray | None] | None = None) -> np.ndarray:
    """Per-pixel scale ratio ``[T,H,W]`` from reference observations (frame [M] int, uv [M,2] px, depth [M]
    prior metres, ratio [M]; non-finite ratios are skipped; thin them first, :func:`thinned_observations`)
    over the prior ``[T,H,W]``: the appendix's consistent video depth is ``ratio * prior``. Frames without a
    reference keep ratio 1. The frames run on ``threads`` threads (``optim.parallel.each_frame``; the same maps
    on any number; 30 frames at 854x480 from the same references: 9.4 s on one thread, 6.5 s on 2 cores).
    ``neighbours(t)``: frame ``t``'s kNN search when already done, the indices ``[H*W,k]`` among its references in
    their order (:func:`pixel_neighbours`), or None (searched here); used only where every ratio is finite (else
    the references it indexes are not the ones used)."""
    T, H, W = prior.shape
    pix = pixel_grid(H, W)
    out = np.ones((T, H, W), np.float32)
    ok = np.isfinite(ref_ratio)
    if not ok.all():
        neighbours = None
    frame, ref_uv, ref_depth, ref_ratio = frame[ok], ref_uv[ok], ref_depth[ok], ref_ratio[ok]
    order = np.argsort(frame, kind="stable")
    bounds = np.searchsorted(frame[order], np.arange(T + 1))

    def frame_map(t: int) -> None:
        v = order[bounds[t]:bounds[t + 1]]
        idx = None if neighbours is None else neighbours(t)
        if len(v):
            out[t] = propagate_ratio(ref_uv[v], ref_depth[v], ref_ratio[v], pix, prior[t].ravel(), K,
                                     k, idx=idx).reshape(H, W)

    each_frame(frame_map, range(T), threads)
    return out


def pixel_neighbours(ref_uv: np.ndarray, pixels: np.ndarray, k: int = 4, workers: int = 1) -> np.ndarray | None:
    """One frame's kNN search of :func:`ratio_maps`, ahead of it: the indices ``[h*w,k]`` int32 of the ``k`` nearest
    of the frame's references ``ref_uv [R,2]`` px (in their order) to each of ``pixels`` (:func:`pixel_grid` of the
    image, as :func:`ratio_maps` queries them); None where there are none. Int32 for half the memory (a frame of
    854x480 pixels, k = 4: 6.6 MB)."""
    if not len(ref_uv):
        return None
    return nearest_references(ref_uv, pixels, k, workers).astype(np.int32)
