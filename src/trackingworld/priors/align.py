"""Relative (affine-invariant) disparity from a depth model -> depth the optimiser can use.

A relative model predicts inverse depth up to an unknown scale and shift per frame. Each frame's
``s * disparity + b`` is fitted, robustly (iteratively reweighted least squares with a Cauchy weight), to the
inverse of a reference depth on the static pixels: the structure-from-motion depth of the video itself, whose
scale is arbitrary but the same in every frame. Without a reference (a camera that hardly moves) the shift is
taken as zero and the median depth set to 1: depth then has the right ordering but a wrong "stretch", and the
scale is arbitrary.
"""

from __future__ import annotations

import numpy as np


def fit_scale_shift(x: np.ndarray, y: np.ndarray, iters: int = 8) -> tuple[float, float]:
    """Robust ``y ~ s x + b`` over samples ``x, y [M]``."""
    w = np.ones_like(x)
    s, b = 1.0, 0.0
    for _ in range(iters):
        A = np.stack([x * w, w], 1)
        s, b = np.linalg.lstsq(A, y * w, rcond=None)[0]
        r = y - (s * x + b)
        c = 2.385 * 1.4826 * np.median(np.abs(r)) + 1e-12
        w = np.sqrt(1.0 / (1.0 + (r / c) ** 2))
    return float(s), float(b)


def disparity_to_depth(disp: np.ndarray, ref_depth: np.ndarray | None, static: np.ndarray | None,
                       max_samples: int = 20000, seed: int = 0) -> np.ndarray:
    """disp [T,H,W] relative inverse depth; ref_depth [T,H,W] (or None) and static [T,H,W] bool -> depth [T,H,W]."""
    T = disp.shape[0]
    out = np.empty(disp.shape, np.float32)
    rng = np.random.default_rng(seed)
    for t in range(T):
        d = disp[t].astype(np.float64)
        if ref_depth is None:
            pos = d[d > 0]
            med = np.median(pos) if pos.size else 1.0
            inv = np.maximum(d / med, 1e-3)
        else:
            sel = np.flatnonzero((static[t] if static is not None else np.ones_like(d, bool)).ravel())
            if len(sel) > max_samples:
                sel = rng.choice(sel, max_samples, replace=False)
            s, b = fit_scale_shift(d.ravel()[sel], 1.0 / np.maximum(ref_depth[t].ravel()[sel], 1e-6))
            inv = s * d + b
            floor = np.percentile(1.0 / ref_depth[t], 1) * 0.5  # nothing farther than twice the far static depth
            inv = np.maximum(inv, floor)
        out[t] = 1.0 / inv
    return out
