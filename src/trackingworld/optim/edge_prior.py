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

from functools import lru_cache

import cv2
import numpy as np

from trackingworld.image import sample_image
from trackingworld.optim.parallel import each_frame

GRAD_LOG_PER_PX = 0.03  # log depth per px at which a pixel's weight falls to 1/e (a blurred edge is steeper)
MIN_SUPPORT = 1e-3  # normalised-convolution weight below which a pixel keeps the prior


def inner_prior(prior: np.ndarray, uv: np.ndarray, vis: np.ndarray, sigma: float,
                grad: float = GRAD_LOG_PER_PX) -> np.ndarray:
    """``[T,H,W]`` float32 metres: the prior ``[T,H,W]`` averaged in log over the pixels covered by the tracks
    ``uv [n,T,2]`` px where visible (``vis [n,T]``), weighted by ``exp(-(|grad log prior| / grad)^2)`` with a
    Gaussian of ``sigma`` px (module docstring); the prior itself where no track is near. In float32 (log depth to
    1e-7; 120 frames at 320x240 over 87k tracks: 0.55 -> 0.31 s); each frame's covered pixels are marked in that
    frame's thread (120 frames, 9.9M visible observations: one pass over all of them first, 0.44 s for the whole
    -> 0.27 s). The same maps from call to call only with OpenCV's IPP off (``trackingworld.reproducible``): IPP's
    blur gives other last bits as memory moves."""
    T, H, W = prior.shape
    vis_t = np.ascontiguousarray(vis.T)  # [T,N]: each frame's covered pixels marked in its own thread
    out = np.empty((T, H, W), np.float32)

    def frame(f: int) -> None:
        v = np.flatnonzero(vis_t[f])
        p = np.rint(uv[v, f]).astype(np.int64)
        p = p[(p[:, 0] >= 0) & (p[:, 0] < W) & (p[:, 1] >= 0) & (p[:, 1] < H)]
        support = np.zeros((H, W), np.float32)
        support[p[:, 1], p[:, 0]] = 1.0
        log_d = np.log(np.maximum(prior[f], 1e-6, dtype=np.float32))
        g = cv2.magnitude(cv2.Sobel(log_d, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(log_d, cv2.CV_32F, 0, 1, ksize=3))
        w = support * np.exp(-np.square(g * np.float32(1 / (8 * grad))))
        num = cv2.GaussianBlur(w * log_d, (0, 0), sigma)
        den = cv2.GaussianBlur(w, (0, 0), sigma)
        out[f] = np.where(den > MIN_SUPPORT, np.exp(num / np.maximum(den, np.float32(1e-12))), prior[f])

    each_frame(frame, range(T))  # frames on the CPUs' threads (OpenCV and numpy let go of the GIL): the same maps
    return out


EDGE_REACH_PX = 6  # a depth step is measured between the points this far either side of its edge's centre
EDGE_STEP_LOG = 0.15  # log-depth steps smaller than this are not depth edges (surface slopes, the prior's noise)
EDGE_GRAD_LOG_PER_PX = 0.03  # edge centres are gradient maxima steeper than this
EDGE_HALF_STEP = 0.95  # a step across the full reach below this times the step across half of it: a thin object
MIN_EDGE_PIXELS = 200  # edge centres needed for an estimate
BLUR_SIGMAS = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0)  # px: the calibration's blurs (a wider one is read as 4)


def edge_widths(log_depth: np.ndarray, reach: int = EDGE_REACH_PX) -> np.ndarray:
    """[E] px: the width of each depth edge of one log-depth image ``[H,W]``, its step over its steepest slope.
    Read at the edge centres: local maxima of the gradient along its direction, steeper than
    EDGE_GRAD_LOG_PER_PX, where the step between ``reach`` px either side is at least EDGE_STEP_LOG and not less
    than the step between ``reach / 2`` px either side (the far side of an object narrower than the reach turns
    the step back). A sharp step reads 2 (the central difference spreads it over two pixels), one blurred by a
    Gaussian of sigma px about 2.2 sigma + 0.8 for sigma of 1 px or more."""
    L = np.ascontiguousarray(log_depth, dtype=np.float32)
    gx = cv2.Sobel(L, cv2.CV_32F, 1, 0, ksize=3, scale=1 / 8)
    gy = cv2.Sobel(L, cv2.CV_32F, 0, 1, ksize=3, scale=1 / 8)
    g = cv2.magnitude(gx, gy)
    H, W = L.shape
    ys, xs = np.nonzero(g > EDGE_GRAD_LOG_PER_PX)
    inside = (xs > reach + 1) & (xs < W - reach - 2) & (ys > reach + 1) & (ys < H - reach - 2)
    ys, xs = ys[inside], xs[inside]
    if not len(xs):
        return np.zeros(0, np.float32)
    gc = g[ys, xs]
    nx, ny = gx[ys, xs] / gc, gy[ys, xs] / gc

    def along(img, d):  # img at d px along each edge pixel's gradient direction (bilinear; sample_image lays the
        # points out in rows, as cv2.remap takes maps below 32767 px a side: a real video's prior has more edge pixels)
        return sample_image(img, np.stack([xs + d * nx, ys + d * ny], 1).astype(np.float32))

    centre = (gc >= along(g, 1)) & (gc >= along(g, -1))
    step = along(L, reach) - along(L, -reach)
    half = along(L, reach / 2) - along(L, -reach / 2)
    # a step, not a thin object (the far side of a pole narrower than the reach turns the step back)
    keep = centre & (step > EDGE_STEP_LOG) & (step >= EDGE_HALF_STEP * half)
    return step[keep] / gc[keep]


@lru_cache(maxsize=1)
def _width_of_blur() -> np.ndarray:
    """[len(BLUR_SIGMAS)] px: the median edge width :func:`edge_widths` reads on a slanted step blurred by each of
    BLUR_SIGMAS (measured, so that the calibration and the estimate are the same code)."""
    ys, xs = np.mgrid[0:120, 0:120]
    step = np.where(xs + 0.3 * ys > 70, np.log(2.0), 0.0).astype(np.float32)
    out = []
    for s in BLUR_SIGMAS:
        img = cv2.GaussianBlur(step, (0, 0), s) if s > 0 else step
        out.append(float(np.median(edge_widths(img))))
    return np.maximum.accumulate(np.asarray(out))


def edge_blur_px(prior: np.ndarray, frames: int = 8) -> float | None:
    """The depth prior's blur at its depth edges: the sigma (px) of the Gaussian that, applied to a sharp step,
    gives the median edge width (:func:`edge_widths`) of ``frames`` frames of ``prior [T,H,W]`` metres spread over
    the video. None where the prior has fewer than MIN_EDGE_PIXELS edge centres (a flat or constant prior). The
    synthetic priors blurred by 1 and 2 px read 1.05-1.12 and 2.05-2.14 (twenty-four scenes); 5 ms at 320x240."""
    T = len(prior)
    widths = [edge_widths(np.log(np.maximum(prior[f], 1e-6, dtype=np.float32)))
              for f in np.unique(np.linspace(0, T - 1, min(frames, T)).round().astype(int))]
    w = np.concatenate(widths) if widths else np.zeros(0)
    if len(w) < MIN_EDGE_PIXELS:
        return None
    return float(np.interp(np.median(w), _width_of_blur(), BLUR_SIGMAS))
