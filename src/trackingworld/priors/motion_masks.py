"""Weight-free dynamic masks from motion: pixels whose motion the camera's cannot explain.

For frame pairs ``(t, t +- gap)`` a fundamental matrix is fitted robustly (OpenCV USAC-MAGSAC) to a spread-out
subset of the dense tracks; where a homography explains nearly as many tracks (a rotating or fixed camera, a
planar or a distant scene: F is then ill-posed, and its spare freedom explains movers) the homography is used
instead, and so it is where the pair is a fixed camera's whose tracks' drift no homography explains either
(:mod:`trackingworld.priors.drift`). A track's residual (Sampson distance, or
transfer error) over its noise level scores its motion in both frames of the pair; per frame, the scores of the
visible tracks vote per pixel, and the voted mask is cleaned (closing, small regions dropped, holes filled) and
smoothed over time (majority of three frames). A long gap (10 frames) lets slow movers build up motion. Movers
that slide along their epipolar lines are not caught here; stage 2 of the optimiser catches those as moving
background.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import binary_fill_holes

from trackingworld.optim.densify import cell_representatives
from trackingworld.priors.drift import pair_looks_fixed, sampson_px, transfer_px
from trackingworld.priors.fill import splat
from trackingworld.tracking2d.base import TrackResult


@dataclass
class MotionMaskConfig:
    gap: int = 10  # frames between the two views of a pair (shorter videos: the farther end)
    min_px: float = 1.5  # smallest residual threshold (px)
    noise_mult: float = 4.0  # threshold = max(min_px, noise_mult * robust sigma of the inliers)
    # use H when its inliers reach this share of F's. The inlier share of H over F's tells a camera that moves
    # (stop 85: 0.25-0.79 over the pairs of seeds 0 and 2's 30- and 120-frame videos of bench_scaling.py, 0.52-0.71
    # on dog.mp4) from one that does not travel (0.86-0.96 on seed 0's 120 frames with cam_speed and cam_turn_deg 0;
    # 0.84-0.91 on sheep.mp4's pan); with 0.95 F took the fixed camera's pairs and explained its movers: the masks'
    # IoU 0.324, recall 0.405, against 0.645 / 0.970 with 0.82 (docs/priors.md). ORB-SLAM's initialisation draws the
    # line at about the same place (H when its score is 0.45 of the two's sum, 0.82 of F's)
    homography_ratio: float = 0.82
    fit_cell: int = 8  # one track per cell of this many px fits the models
    max_fit: int = 8000
    vote: float = 0.5  # share of moving tracks among the tracks near a pixel that makes it dynamic
    min_region: float = 0.002  # regions smaller than this share of the image are dropped
    dilate_px: int = 1  # the masks are coarse, like the paper's: grown by a few pixels
    border: float = 0.02  # observations this close to the image border (share of the short side) do not vote:
    # tracks entering or leaving the image carry the flow's worst errors
    verbose: bool = True


def fit_two_view(a: np.ndarray, b: np.ndarray):
    """Robust fundamental matrix and homography (USAC-MAGSAC) of correspondences ``a -> b [M,2]`` pixels.

    Returns (F [3,3] or None, F inlier mask [M] bool, H [3,3] or None, H inlier mask [M] bool); None when OpenCV
    rejects the sample (it raises on degenerate ones, e.g. no motion at all)."""
    a, b = a.astype(np.float64), b.astype(np.float64)
    try:
        F, inl_f = cv2.findFundamentalMat(a, b, cv2.USAC_MAGSAC, 1.0, 0.999, 2000)
        Hm, inl_h = cv2.findHomography(a, b, cv2.USAC_MAGSAC, 1.5, maxIters=2000, confidence=0.999)
    except cv2.error:
        return None
    if F is None or F.shape != (3, 3) or inl_f is None:
        F, inl_f = None, np.zeros(len(a), bool)
    if Hm is None or inl_h is None:
        Hm, inl_h = None, np.zeros(len(a), bool)
    return F, inl_f.ravel() > 0, Hm, inl_h.ravel() > 0


def _pair_residuals(pa: np.ndarray, pb: np.ndarray, fit: np.ndarray, cfg: MotionMaskConfig):
    """Residuals [M] (px) of correspondences ``pa -> pb [M,2]`` under the camera's motion fitted on ``fit``, and
    the residual threshold (px). None when the fit fails."""
    fits = fit_two_view(pa[fit], pb[fit])
    if fits is None:
        return None
    F, inl_f, Hm, inl_h = fits
    n_f, n_h = int(inl_f.sum()), int(inl_h.sum())
    if n_f == 0 and n_h == 0:
        return None
    use_h = Hm is not None and n_h >= cfg.homography_ratio * n_f  # a camera that does not travel
    if not use_h and Hm is not None and F is not None:  # a fixed camera's drift, which neither model explains
        # (pstudio.mp4, where H's inliers are 0.71-0.79 of F's: priors.drift)
        use_h = pair_looks_fixed(pa[fit], pb[fit], F, transfer_px(pa[fit], pb[fit], Hm))
    if use_h:
        r, inl = transfer_px(pa, pb, Hm), inl_h
    else:
        r, inl = sampson_px(F, pa, pb), inl_f
    sigma = 1.4826 * np.median(r[fit][inl]) if inl.any() else cfg.min_px
    return r, max(cfg.min_px, cfg.noise_mult * sigma)


def partner_frame(t: int, T: int, gap: int) -> int:
    """The frame ``t`` is compared with: ``gap`` later, else ``gap`` earlier, else the farther end of the video."""
    if t + gap < T:
        return t + gap
    if t - gap >= 0:
        return t - gap
    return T - 1 if T - 1 - t >= t else 0


def motion_scores(tr: TrackResult, cfg: MotionMaskConfig, rng: np.random.Generator) -> np.ndarray:
    """Per-observation motion score ``[N,T]`` float32 (residual / threshold; > 1 = moving, NaN = not tested)."""
    uv, vis = tr.tracks, tr.visible
    N, T = vis.shape
    fit_idx = cell_representatives(tr.queries, cfg.fit_cell)
    if len(fit_idx) > cfg.max_fit:
        fit_idx = np.sort(rng.choice(fit_idx, cfg.max_fit, replace=False))
    is_fit = np.zeros(N, bool)
    is_fit[fit_idx] = True
    score = np.full((N, T), np.nan, np.float32)
    partner = {t: partner_frame(t, T, cfg.gap) for t in range(T)}
    for a, b in sorted({tuple(sorted((t, p))) for t, p in partner.items()}):
        both = np.flatnonzero(vis[:, a] & vis[:, b])
        fit = is_fit[both]
        if fit.sum() < 16:
            continue
        out = _pair_residuals(uv[both, a], uv[both, b], fit, cfg)
        if out is None:
            continue
        r, thr = out
        for f, g in ((a, b), (b, a)):
            if partner[f] == g:
                score[both, f] = r / thr
    return score


def _clean(mask: np.ndarray, cfg: MotionMaskConfig) -> np.ndarray:
    H, W = mask.shape
    m = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((7, 7), np.uint8))
    n, lab, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    keep = np.flatnonzero(stats[:, cv2.CC_STAT_AREA] >= cfg.min_region * H * W)
    keep = keep[keep > 0]
    return binary_fill_holes(np.isin(lab, keep))


def motion_masks(tr: TrackResult, shape: tuple[int, int, int], cfg: MotionMaskConfig | None = None,
                 seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Dynamic masks ``[T,H,W]`` bool and the per-observation scores ``[N,T]`` from dense tracks ``tr``
    (processing resolution, frames of ``shape = (T, H, W)``)."""
    cfg = cfg or MotionMaskConfig()
    T, H, W = shape
    score = motion_scores(tr, cfg, np.random.default_rng(seed))
    raw = np.zeros((T, H, W), bool)
    k = np.ones((9, 9), np.float32)
    b = cfg.border * min(H, W)
    inside = ((tr.tracks[..., 0] >= b) & (tr.tracks[..., 0] <= W - 1 - b) & (tr.tracks[..., 1] >= b)
              & (tr.tracks[..., 1] <= H - 1 - b))
    for t in range(T):
        v = np.flatnonzero(tr.visible[:, t] & np.isfinite(score[:, t]) & inside[:, t])
        if not len(v):
            continue
        mov, allv = splat(tr.tracks[v, t], (score[v, t] > 1).astype(np.float64), np.ones(len(v)), H, W)
        mov, allv = cv2.filter2D(mov, -1, k), cv2.filter2D(allv, -1, k)
        raw[t] = (mov > cfg.vote * allv) & (allv > 0)
    smooth = raw.copy()
    if T >= 3:
        votes = raw[:-2].astype(np.int8) + raw[1:-1] + raw[2:]
        smooth[1:-1] = votes >= 2
    out = np.zeros_like(smooth)
    kd = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * cfg.dilate_px + 1,) * 2)
    for t in range(T):
        out[t] = cv2.dilate(_clean(smooth[t], cfg).astype(np.uint8), kd) > 0
    if cfg.verbose:
        print(f"[masks] motion masks: {out.mean() * 100:.1f}% of the pixels dynamic", file=sys.stderr)
    return out, score
