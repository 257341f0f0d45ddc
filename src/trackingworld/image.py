"""Sampling images at sub-pixel points: the colours and patches the 2D tracker's checks and the lifting's
photometric tests compare, and the maps (depth, flow, fields) read at track positions.

Conventions: points ``[M,2]`` float32 pixels, x right and y down, pixel centres at integers.
"""

from __future__ import annotations

import cv2
import numpy as np


def sample_image(img: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Bilinear sample of ``img [H,W(,C)]`` at ``pts [M,2]`` (border replicated) -> ``[M(,C)]``.

    OpenCV's remap takes maps below 32767 per side, so points are laid out in rows of 1024."""
    M = len(pts)
    cols = 1024
    rows = max(1, -(-M // cols))
    m = np.zeros((rows * cols, 2), np.float32)
    m[:M] = pts
    m = m.reshape(rows, cols, 2)
    out = cv2.remap(img, m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape((rows * cols,) + img.shape[2:])[:M]


def blurred_frames(frames: np.ndarray, sigma: float = 1.0) -> np.ndarray:
    """``frames [T,H,W,3]`` uint8 -> the same blurred by a Gaussian of ``sigma`` px, uint8: the colours the colour
    checks compare (here, and the lifting's photometric static test, ``optim.photo_static``)."""
    return np.stack([cv2.GaussianBlur(f, (0, 0), sigma) for f in frames])


def patch_offsets(radius: int) -> np.ndarray:
    """``[(2 radius + 1)^2, 2]`` float32: the pixel offsets (x, y) of a square patch of half-side ``radius``."""
    r = np.arange(-radius, radius + 1, dtype=np.float32)
    return np.stack(np.meshgrid(r, r), -1).reshape(-1, 2)


def sample_patches(img: np.ndarray, pts: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """``[M,P,C]`` float32: ``img [H,W,C]`` bilinearly sampled at ``pts [M,2]`` plus each of ``offsets [P,2]`` px,
    each patch's mean colour removed (an even change of brightness does not count)."""
    M, P = len(pts), len(offsets)
    v = sample_image(img, (pts[:, None, :] + offsets[None]).reshape(-1, 2)).reshape(M, P, -1).astype(np.float32)
    return v - v.mean(1, keepdims=True)
