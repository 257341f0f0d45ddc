"""Turning exact depth and instance maps into the imperfect priors a user would have."""

from __future__ import annotations

import cv2
import numpy as np

from trackingworld.synth.scene import SceneConfig


def corrupt_depth(depth: np.ndarray, cfg: SceneConfig, rng: np.random.Generator) -> np.ndarray:
    """Depth ``[T,H,W]`` -> a monocular-depth-model-like prior: per-frame scale error, a smooth
    low-frequency multiplicative warp that drifts over time, edge blur and pixel noise."""
    T, H, W = depth.shape
    ys, xs = np.mgrid[0:H, 0:W] / max(H, W)
    out = np.empty_like(depth)
    scales = 1.0 + cfg.prior_scale_std * rng.standard_normal(T)
    freqs = rng.uniform(0.5, 2.0, size=(3, 2))
    phases = rng.uniform(0, 2 * np.pi, size=3)
    drift = rng.uniform(0.02, 0.08, size=3)
    for t in range(T):
        warp = np.zeros((H, W))
        for k in range(3):
            warp += np.cos(2 * np.pi * (freqs[k, 0] * xs + freqs[k, 1] * ys) + phases[k] + drift[k] * t)
        warp = 1.0 + cfg.prior_distortion * warp / 3.0
        d = depth[t] * warp * scales[t]
        if cfg.prior_blur_px > 0:
            d = cv2.GaussianBlur(d.astype(np.float32), (0, 0), cfg.prior_blur_px)
        noise = cv2.GaussianBlur(rng.standard_normal((H, W)).astype(np.float32), (0, 0), 1.0) * 2.0
        out[t] = d * (1.0 + cfg.prior_noise * noise)
    return np.maximum(out, 1e-3).astype(np.float32)


def coarse_masks(moving_masked: np.ndarray, cfg: SceneConfig, rng: np.random.Generator) -> np.ndarray:
    """Exact masks ``[T,H,W]`` of the masked movers -> coarse masks: dilated by a few pixels, with a
    per-frame jitter of the dilation, as a segmentation model's output would be."""
    out = np.zeros_like(moving_masked)
    for t in range(moving_masked.shape[0]):
        r = max(1, cfg.mask_dilate_px + int(rng.integers(-2, 3)))
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        out[t] = cv2.dilate(moving_masked[t].astype(np.uint8), kernel) > 0
    return out
