"""Sparse samples -> a dense map: push-pull (normalised convolution over an image pyramid).

Written by hand because OpenCV's inpainting fills holes by diffusing colour across edges pixel by pixel (slow
for large holes) and scipy's ``griddata`` triangulates every sample (slow for 10^5 samples); push-pull is
linear in the pixels and fills holes of any size from their surroundings.
"""

from __future__ import annotations

import cv2
import numpy as np


def splat(uv: np.ndarray, values: np.ndarray, weights: np.ndarray, H: int, W: int) -> tuple[np.ndarray, np.ndarray]:
    """Weighted sum of ``values [M]`` and of ``weights [M]`` at the rounded pixels ``uv [M,2]`` -> ([H,W], [H,W])."""
    x = np.round(uv[:, 0]).astype(np.int64)
    y = np.round(uv[:, 1]).astype(np.int64)
    ok = (x >= 0) & (x < W) & (y >= 0) & (y < H) & np.isfinite(values) & (weights > 0)
    idx = y[ok] * W + x[ok]
    vw = np.bincount(idx, weights=values[ok] * weights[ok], minlength=H * W).reshape(H, W)
    w = np.bincount(idx, weights=weights[ok], minlength=H * W).reshape(H, W)
    return vw, w


def push_pull(vw: np.ndarray, w: np.ndarray, full_weight: float = 1.0) -> np.ndarray:
    """Dense ``[H,W]`` map from weighted sums ``vw`` and weights ``w``: each level keeps its own average where its
    weight reaches ``full_weight`` and blends towards the coarser level's estimate where it has less."""
    levels = [(vw.astype(np.float64), w.astype(np.float64))]
    while min(levels[-1][1].shape) > 1:
        a, b = levels[-1]
        h, wd = max(1, a.shape[0] // 2), max(1, a.shape[1] // 2)
        levels.append((cv2.resize(a, (wd, h), interpolation=cv2.INTER_AREA) * 4,
                       cv2.resize(b, (wd, h), interpolation=cv2.INTER_AREA) * 4))
    a, b = levels[-1]
    total = w.sum()
    est = np.where(b > 0, a / np.maximum(b, 1e-12), vw.sum() / total if total > 0 else 0.0)
    for a, b in reversed(levels[:-1]):
        up = cv2.resize(est, (a.shape[1], a.shape[0]), interpolation=cv2.INTER_LINEAR)
        alpha = np.clip(b / full_weight, 0, 1)
        est = alpha * (a / np.maximum(b, 1e-12)) + (1 - alpha) * up
    return est


def densify(uv: np.ndarray, values: np.ndarray, H: int, W: int, weights: np.ndarray | None = None) -> np.ndarray:
    """Samples ``values [M]`` at pixels ``uv [M,2]`` -> dense ``[H,W]`` float32 map."""
    weights = np.ones(len(values)) if weights is None else weights
    vw, w = splat(uv, values, weights, H, W)
    return push_pull(vw, w).astype(np.float32)
