"""Depth metrics: Abs Rel and delta<1.25 after one scale and shift per sequence.

Two fitting conventions exist in the field and both are provided:
* ``depth``: MonST3R's, in depth space: median-ratio start, then L1 refinement;
* ``disparity``: DepthCrafter's, least squares on inverse depth.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar


def fit_scale_shift_depth(pred: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    """(s, b) minimising sum |s*pred + b - gt| (L1).

    For a fixed s the best b is the median of ``gt - s*pred``, and the remaining function of s is convex,
    so a bounded scalar search around the median-ratio start finds the global L1 optimum.
    """
    p = pred.astype(np.float64)
    g = gt.astype(np.float64)
    s0 = float(np.median(g) / max(np.median(p), 1e-12))

    def cost(s: float) -> float:
        r = g - s * p
        return float(np.abs(r - np.median(r)).mean())

    lo, hi = (s0 / 20, s0 * 20) if s0 > 0 else (-1e3, 1e3)
    res = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 1e-9 * max(abs(s0), 1)})
    s = float(res.x) if cost(res.x) <= cost(s0) else s0
    return s, float(np.median(g - s * p))


def fit_scale_shift_disparity(pred: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    """(s, b) minimising sum (s/pred + b - 1/gt)^2."""
    A = np.stack([1.0 / pred, np.ones_like(pred)], 1).astype(np.float64)
    sol, *_ = np.linalg.lstsq(A, 1.0 / gt.astype(np.float64), rcond=None)
    return float(sol[0]), float(sol[1])


def align_depth(pred: np.ndarray, gt: np.ndarray, space: str = "depth") -> np.ndarray:
    """Apply the per-sequence scale+shift fitted on the given (already masked, 1-D) samples."""
    if space == "depth":
        s, b = fit_scale_shift_depth(pred, gt)
        return s * pred + b
    if space == "disparity":
        s, b = fit_scale_shift_disparity(pred, gt)
        disp = np.maximum(s / pred + b, 1e-6)
        return 1.0 / disp
    raise ValueError(f"unknown alignment space {space!r}")


def abs_rel_delta1(pred: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    pred = np.maximum(pred, 1e-6)
    abs_rel = float(np.mean(np.abs(pred - gt) / gt))
    d1 = float(np.mean(np.maximum(pred / gt, gt / pred) < 1.25))
    return abs_rel, d1


def depth_metrics(pred: np.ndarray, gt: np.ndarray, valid: np.ndarray | None = None,
                  max_depth: float | None = None) -> dict:
    """Abs Rel and delta1 in both alignment spaces over the valid pixels of a whole sequence."""
    valid = np.ones(gt.shape, bool) if valid is None else valid.copy()
    valid &= np.isfinite(gt) & (gt > 0) & np.isfinite(pred) & (pred > 0)
    if max_depth is not None:
        valid &= gt <= max_depth
    p, g = pred[valid].astype(np.float64), gt[valid].astype(np.float64)
    out = {"n_pixels": int(valid.sum())}
    if p.size < 2:
        return out
    for space in ("depth", "disparity"):
        ar, d1 = abs_rel_delta1(align_depth(p, g, space), g)
        out[f"abs_rel_{space}"] = ar
        out[f"delta1_{space}"] = d1
    return out
