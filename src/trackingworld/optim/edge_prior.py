"""The depth prior away from its blurred depth edges, each side of an edge read from its own tracks.

A monocular depth prior blurs across depth edges, so a mover's rim pixels read part of the background's depth
(the synthetic priors: `hard` seed 0, dynamic ground-truth tracks within 2 px of their object's edge have a
prior 10% too far on the median, 3% at 4-7 px), and stage 3 puts those tracks behind their object. ARAP does
not pull them back: it holds the offsets between neighbours constant over time, and a rim track's bias is
nearly constant.

Per frame, the log prior is averaged over the pixels the dynamic tracks cover (so the background does not
leak in), each pixel weighted down by the log prior's gradient there (``exp(-(|grad log D| / grad)^2)``: the
blurred edge is where the gradient is steep), with a Gaussian of ``sigma`` px (normalised convolution). A rim
pixel then reads its object's inner depth; an inner pixel about its own, smoothed over ``sigma`` px. Pixels
the tracks do not cover keep the prior.

The pipeline runs it twice (``OptimConfig.dc_edge_sigma_px``): over the static tracks for stages 1-2 (the
background beside a mover reads the background's depth, not the blur toward the mover's) and over the dynamic
tracks for stage 3's target.
"""

from __future__ import annotations

import cv2
import numpy as np

GRAD_LOG_PER_PX = 0.03  # log depth per px at which a pixel's weight falls to 1/e (a blurred edge is steeper)
MIN_SUPPORT = 1e-3  # normalised-convolution weight below which a pixel keeps the prior


def inner_prior(prior: np.ndarray, uv: np.ndarray, vis: np.ndarray, sigma: float,
                grad: float = GRAD_LOG_PER_PX) -> np.ndarray:
    """``[T,H,W]`` float32 metres: the prior ``[T,H,W]`` averaged in log over the pixels covered by the tracks
    ``uv [n,T,2]`` px where visible (``vis [n,T]``), weighted by ``exp(-(|grad log prior| / grad)^2)`` with a
    Gaussian of ``sigma`` px (module docstring); the prior itself where no track is near. In float32 (log depth to
    1e-7; 120 frames at 320x240 over 87k tracks: 0.55 -> 0.31 s): the covered pixels of every frame are marked in
    one pass over the visible observations instead of a gather per frame."""
    T, H, W = prior.shape
    n, t = np.nonzero(vis)
    p = np.rint(uv[n, t]).astype(np.int64)
    inside = (p[:, 0] >= 0) & (p[:, 0] < W) & (p[:, 1] >= 0) & (p[:, 1] < H)
    support = np.zeros(T * H * W, np.float32)
    support[(t[inside] * H + p[inside, 1]) * W + p[inside, 0]] = 1.0
    support = support.reshape(T, H, W)
    out = np.empty((T, H, W), np.float32)
    for f in range(T):
        log_d = np.log(np.maximum(prior[f], 1e-6, dtype=np.float32))
        g = cv2.magnitude(cv2.Sobel(log_d, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(log_d, cv2.CV_32F, 0, 1, ksize=3))
        w = support[f] * np.exp(-np.square(g * np.float32(1 / (8 * grad))))
        num = cv2.GaussianBlur(w * log_d, (0, 0), sigma)
        den = cv2.GaussianBlur(w, (0, 0), sigma)
        out[f] = np.where(den > MIN_SUPPORT, np.exp(num / np.maximum(den, np.float32(1e-12))), prior[f])
    return out
