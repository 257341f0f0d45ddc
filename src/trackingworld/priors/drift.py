"""A fixed camera told from a moving one by two frames of static tracks (pixels x right, y down).

A fixed camera's tracks drift (chained flow gathers a few tenths of a pixel of error a frame), and the drift reads
as parallax: a homography does not explain it, and the longer the video the more of it there is (the Panoptic
Studio clip of ``../shared/data``, pstudio.mp4, 1.6 / 2.1 / 5.4 / 9.5 px of residual parallax over its first 24 /
40 / 80 / 150 frames). Structure from motion then reconstructs noise and self-calibration finds a focal length in
it. Two things tell such a pair of frames from a moving camera's:

- its tracks move about as much as their parallax, a homography explaining nothing of their motion: over the
  self-calibration's pairs (10 frames apart) pstudio's move 0.8-1.0x their median parallax, the hand-held
  dog.mp4's 22-78x, the synthetic scenes' 30-frame windows' 17-51x; over SfM's starting pair pstudio's 1.9 px for
  2.1 px (40 frames) and 8.6 px for 9.5 px (150), dog's 122 px for 2.4 px. A camera translating by b moves a point
  at depth z by f b / z, and the parallax is a part of that, unless a rotation cancels the motion, as an orbit
  about a point does;
- and a second view does not explain the parallax: the essential matrix fitted to SfM's starting pair leaves a
  median Sampson error of 0.30-0.47x the parallax on pstudio (its first 24 to 150 frames), 0.01-0.12x on the
  synthetic windows and 0.04x on an orbit (``tests/test_priors.py``). Alone this test would not do: dog.mp4's pair
  leaves 0.43x, its parallax smeared by the grass's drift, but its tracks move 51x their parallax.

Both measured at stop 85 (``docs/priors.md``, "Stop 85"). The two residuals the tests read are the weight-free
priors' own, shared by SfM, self-calibration and the motion masks: a homography's transfer error
(:func:`transfer_px`) and a fundamental matrix's Sampson distance (:func:`sampson_px`).
"""

from __future__ import annotations

import cv2
import numpy as np

FIXED_MOTION = 2.0  # the tracks move less than this x their parallax ...
FIXED_EPIPOLAR = 0.2  # ... and a second view leaves more than this x the parallax: a fixed camera's drift


def transfer_px(pa: np.ndarray, pb: np.ndarray, Hm: np.ndarray) -> np.ndarray:
    """Transfer errors ``[n]`` (px) of the matches ``pa -> pb [n,2]`` (px) under the homography ``Hm``."""
    q = cv2.perspectiveTransform(pa.reshape(-1, 1, 2).astype(np.float64), Hm).reshape(-1, 2)
    return np.linalg.norm(q - pb, axis=1)


def sampson_px(F: np.ndarray, pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    """Sampson distances ``[n]`` (px) of the matches ``pa -> pb [n,2]`` (px) under the fundamental matrix ``F``
    (``pb^T F pa = 0``): each pair's first-order distance from the nearest pair the two views explain (the motion
    masks' residual, :mod:`trackingworld.priors.motion_masks`)."""
    xa, xb = np.c_[pa, np.ones(len(pa))], np.c_[pb, np.ones(len(pb))]
    Fa, Fb = xa @ F.T, xb @ F  # the epipolar lines of pa in the second image, of pb in the first
    num = np.abs((xb * Fa).sum(1))
    den = np.sqrt(Fa[:, 0] ** 2 + Fa[:, 1] ** 2 + Fb[:, 0] ** 2 + Fb[:, 1] ** 2)
    return num / np.maximum(den, 1e-12)


def looks_fixed(motion_px: float, parallax_px: float, epipolar_px: float, fixed_motion: float = FIXED_MOTION,
                fixed_epipolar: float = FIXED_EPIPOLAR) -> bool:
    """Whether a pair of frames is a fixed camera's: its static tracks' median motion ``motion_px``, their
    residual parallax after a homography ``parallax_px`` and the median Sampson error of the epipolar geometry
    fitted to them ``epipolar_px`` (px; see the module docstring)."""
    return motion_px < fixed_motion * parallax_px and epipolar_px > fixed_epipolar * parallax_px


def pair_looks_fixed(pa: np.ndarray, pb: np.ndarray, F: np.ndarray, transfer_px: np.ndarray,
                     fixed_motion: float = FIXED_MOTION, fixed_epipolar: float = FIXED_EPIPOLAR) -> bool:
    """:func:`looks_fixed` of the matches ``pa -> pb [n,2]`` (px), given the fundamental matrix ``F`` fitted to them
    and a homography's transfer errors ``transfer_px [n]`` (px) on them: the medians of their motion, of those
    errors and of their Sampson distances."""
    pa, pb = pa.astype(np.float64), pb.astype(np.float64)
    return looks_fixed(float(np.median(np.linalg.norm(pb - pa, axis=1))), float(np.median(transfer_px)),
                       float(np.median(sampson_px(F, pa, pb))), fixed_motion, fixed_epipolar)
