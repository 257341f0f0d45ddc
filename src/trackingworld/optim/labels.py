"""Labelling tracks static / dynamic / ambiguous from coarse dynamic masks (paper Sec. 3.3, first step)."""

from __future__ import annotations

import cv2
import numpy as np

from trackingworld.geometry import nearest_pixel

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
    # frame by frame: the sure-static / sure-dynamic lookups of the visible observations, each frame's gathered
    # from the tracks (a long video's hidden entries of [N,T] outnumber its visible ones: no copy of them all)
    vis_t = np.ascontiguousarray(visible.T)
    n_sta = np.zeros(N, np.int64)
    n_dyn = np.zeros(N, np.int64)
    for t in range(T):
        v = np.flatnonzero(vis_t[t])
        x, y = nearest_pixel(tracks[v, t], W, H)
        flat = y * W + x
        n_sta[v] += sta[t].ravel()[flat]
        n_dyn[v] += dyn[t].ravel()[flat]
    nvis = np.maximum(visible.sum(1), 1)
    q = query_frame.astype(np.int64)
    qx, qy = nearest_pixel(tracks[np.arange(N), q], W, H)
    q_static = sta[q, qy, qx]
    labels = np.full(N, AMBIGUOUS, np.int8)
    labels[q_static & (n_sta * 2 >= nvis)] = STATIC
    labels[n_dyn * 2 > nvis] = DYNAMIC
    return labels


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
