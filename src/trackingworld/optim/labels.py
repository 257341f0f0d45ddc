"""Labelling tracks static / dynamic / ambiguous from coarse dynamic masks (paper Sec. 3.3, first step)."""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from trackingworld.geometry import nearest_pixel
from trackingworld.optim.parallel import in_parts, part_bounds, worker_threads

STATIC, DYNAMIC, AMBIGUOUS = 0, 1, 2


def mask_regions(masks: np.ndarray, margin_px: int) -> tuple[np.ndarray, np.ndarray]:
    """Coarse masks ``[T,H,W]`` bool -> (sure static, sure dynamic) ``[T,H,W]`` bool: each region eroded by
    ``margin_px``, so the band of about 2 * margin_px around every mask border belongs to neither."""
    if margin_px <= 0:
        return ~masks, masks.copy()
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin_px + 1, 2 * margin_px + 1))
    m = masks.astype(np.uint8)
    dyn = np.stack([cv2.erode(a, k) for a in m]) > 0
    sta = np.stack([cv2.erode(1 - a, k) for a in m]) > 0
    return sta, dyn


def label_tracks(tracks: np.ndarray, visible: np.ndarray, query_frame: np.ndarray, masks: np.ndarray,
                 margin_px: int = 2) -> np.ndarray:
    """Per-track labels ``[N]`` int8 (STATIC, DYNAMIC, AMBIGUOUS).

    tracks [N,T,2] pixels, visible [N,T], query_frame [N], masks [T,H,W] (True = dynamic object).
    Static: the query frame and at least half of the visible frames in the sure-static region (as the
    authors). Dynamic: more than half of the visible frames in the sure-dynamic region (the authors ask for
    all frames and drop the rest; a coarse mask that misses a frame should not make a mover static).
    Everything else is ambiguous and is decided by the stage-2 offset test.
    """
    N, T = visible.shape
    H, W = masks.shape[1:]
    sta, dyn = mask_regions(masks, margin_px)
    # per track the sure-static / sure-dynamic lookups of its visible observations, compiled, the tracks in parts on
    # the CPUs' threads (120 frames, 257k tracks: the labels 0.40 s with a numpy loop over the frames -> 0.10 s)
    px = np.ascontiguousarray(tracks) if tracks.dtype in (np.float32, np.float64) else tracks.astype(np.float64)
    vis = np.ascontiguousarray(visible, np.bool_)
    n_sta, n_dyn = np.zeros(N, np.int64), np.zeros(N, np.int64)
    in_parts(lambda lo, hi: _region_counts(px, vis, sta, dyn, lo, hi, n_sta, n_dyn),
             part_bounds(np.arange(N + 1), worker_threads(), 4096))
    nvis = np.maximum(visible.sum(1), 1)
    q = query_frame.astype(np.int64)
    qx, qy = nearest_pixel(tracks[np.arange(N), q], W, H)
    q_static = sta[q, qy, qx]
    labels = np.full(N, AMBIGUOUS, np.int8)
    labels[q_static & (n_sta * 2 >= nvis)] = STATIC
    labels[n_dyn * 2 > nvis] = DYNAMIC
    return labels


@njit(cache=True, nogil=True)
def _region_counts(tracks, visible, sta, dyn, lo, hi, n_sta, n_dyn):
    """For the tracks ``lo`` to ``hi``: how many of their visible observations (``tracks [N,T,2]`` px, ``visible
    [N,T]``) fall on the sure-static / sure-dynamic regions ``sta``, ``dyn [T,H,W]`` at their nearest pixel
    (``geometry.nearest_pixel``: rounded half to even, clamped to the image), into ``n_sta``, ``n_dyn [N]``."""
    T = visible.shape[1]
    H, W = sta.shape[1], sta.shape[2]
    for i in range(lo, hi):
        for t in range(T):
            if visible[i, t]:
                x = _nearest(tracks[i, t, 0], W)
                y = _nearest(tracks[i, t, 1], H)
                n_sta[i] += sta[t, y, x]
                n_dyn[i] += dyn[t, y, x]


@njit(cache=True, nogil=True)
def _nearest(v, n):
    """``geometry.nearest_pixel`` of one coordinate: ``v`` rounded half to even, clamped to 0 .. n - 1 (a coordinate
    that is not finite, or beyond int64, clamps to 0, as numpy's cast of it does on x86)."""
    r = np.rint(v)
    if not (-9.2e18 <= r <= 9.2e18):
        return 0
    return min(max(int(r), 0), n - 1)


def depth_in_mask(tracks: np.ndarray, query_frame: np.ndarray, masks: np.ndarray) -> np.ndarray:
    """``[N]`` float32 px: how deep each track's query pixel lies inside its query frame's coarse mask (the
    Euclidean distance to the nearest pixel outside it; 0 outside the masks). tracks [N,T,2] px, query_frame
    [N], masks [T,H,W] bool. A coarse mask is the object dilated by a few pixels: a static point it covers lies
    in that band, its core is the object."""
    N = len(query_frame)
    H, W = masks.shape[1:]
    q = query_frame.astype(np.int64)
    x, y = nearest_pixel(tracks[np.arange(N), q], W, H)
    out = np.zeros(N, np.float32)
    for t in np.unique(q):
        s = np.flatnonzero(q == t)
        inside = cv2.distanceTransform(masks[t].astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        out[s] = inside[y[s], x[s]]
    return out
