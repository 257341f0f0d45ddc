"""Focal length from the video alone: epipolar self-calibration on the static tracks.

For a pair of frames with enough parallax, a fundamental matrix F is fitted robustly (USAC-MAGSAC) on static
tracks. With the principal point at the image centre, square pixels and one focal length f, the essential
matrix E = K(f)^T F K(f) must have two equal singular values; the cost (s1 - s2) / (s1 + s2) (Mendonca and
Cipolla, 1999) is evaluated on a log-spaced grid of focal lengths, summed over pairs, and its minimum refined by
a parabola. Pairs that a homography explains as well as F (pure rotation, a planar scene) carry no information
and are skipped, and so are a fixed camera's pairs, whose parallax is its tracks' drift
(:mod:`trackingworld.priors.drift`). When too few pairs remain or the cost has no clear minimum, the caller keeps
its assumed field of view. This replaces the fixed 60 deg guess; the world-centric optimisation then runs with the
estimate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackingworld.priors.drift import FIXED_EPIPOLAR, FIXED_MOTION, pair_looks_fixed, transfer_px
from trackingworld.priors.motion_masks import fit_two_view, partner_frame
from trackingworld.tracking2d.base import TrackResult


@dataclass
class FocalConfig:
    gap: int = 10  # frames between the two frames of a pair
    max_pairs: int = 16
    min_pairs: int = 3
    max_tracks: int = 3000  # per pair
    min_tracks: int = 50
    fov_range_deg: tuple[float, float] = (15.0, 130.0)  # horizontal field of view searched
    grid: int = 240
    min_parallax_px: float = 2.0  # displacement a homography cannot explain, at the percentile below
    parallax_percentile: float = 90.0  # (a wall or floor filling the view lets a homography explain the median)
    homography_ratio: float = 0.9  # skip a pair when H's inliers >= this x F's
    max_depth_ratio: float = 0.6  # the minimum must be below this x the cost's median: else "no clear minimum"
    # skip a pair whose tracks move less than fixed_motion x their median residual parallax and whose F leaves a
    # median Sampson error of more than fixed_epipolar x it: a fixed camera's drift (priors.drift; pstudio.mp4's
    # 150 frames gave a 120 deg field of view from it)
    fixed_motion: float = FIXED_MOTION
    fixed_epipolar: float = FIXED_EPIPOLAR


def essential_cost(F: np.ndarray, focals: np.ndarray, cx: float, cy: float) -> np.ndarray:
    """(s1 - s2) / (s1 + s2) of E = K^T F K for each focal length [G] -> [G]."""
    K = np.zeros((len(focals), 3, 3))
    K[:, 0, 0] = K[:, 1, 1] = focals
    K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = cx, cy, 1.0
    E = np.swapaxes(K, 1, 2) @ F @ K
    s = np.linalg.svd(E, compute_uv=False)
    return (s[:, 0] - s[:, 1]) / np.maximum(s[:, 0] + s[:, 1], 1e-12)


def estimate_focal(tr: TrackResult, static: np.ndarray, size: tuple[int, int], cfg: FocalConfig | None = None,
                   seed: int = 0) -> tuple[float | None, dict]:
    """Focal length in pixels (None when the video does not determine it) and what was found.

    ``tr`` holds tracks [N,T,2] at the processing resolution ``size`` (w, h); ``static`` [N] bool selects the
    tracks to use."""
    cfg = cfg or FocalConfig()
    w, h = size
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    T = tr.tracks.shape[1]
    lo, hi = (w / 2.0 / np.tan(np.deg2rad(a) / 2.0) for a in cfg.fov_range_deg[::-1])
    focals = np.geomspace(lo, hi, cfg.grid)
    rng = np.random.default_rng(seed)
    starts = np.unique(np.linspace(0, T - 1, min(cfg.max_pairs, T)).round().astype(int))
    costs, used, skipped = [], [], {"few_tracks": 0, "homography": 0, "parallax": 0, "fit": 0, "fixed": 0}
    for a in starts:
        b = partner_frame(int(a), T, cfg.gap)
        both = np.flatnonzero(static & tr.visible[:, a] & tr.visible[:, b])
        if len(both) < cfg.min_tracks:
            skipped["few_tracks"] += 1
            continue
        if len(both) > cfg.max_tracks:
            both = rng.choice(both, cfg.max_tracks, replace=False)
        pa = tr.tracks[both, a].astype(np.float64)
        pb = tr.tracks[both, b].astype(np.float64)
        fits = fit_two_view(pa, pb)
        if fits is None or fits[0] is None:
            skipped["fit"] += 1
            continue
        F, inl_f, Hm, inl_h = fits
        n_f = int(inl_f.sum())
        if Hm is not None:
            if int(inl_h.sum()) >= cfg.homography_ratio * n_f:
                skipped["homography"] += 1
                continue
            resid = transfer_px(pa, pb, Hm)
            if np.percentile(resid, cfg.parallax_percentile) < cfg.min_parallax_px:
                skipped["parallax"] += 1
                continue
            if pair_looks_fixed(pa, pb, F, resid, cfg.fixed_motion, cfg.fixed_epipolar):
                skipped["fixed"] += 1
                continue
        c = essential_cost(F, focals, cx, cy)
        costs.append(c / max(np.median(c), 1e-12))  # each pair weighs the same
        used.append((int(a), int(b)))
    info: dict = {"pairs": len(used), "skipped": skipped}
    if len(used) < cfg.min_pairs:
        info["reason"] = f"only {len(used)} usable frame pairs (need {cfg.min_pairs})"
        if skipped["fixed"] >= max(skipped.values()):
            info["reason"] += (f": a fixed camera, the parallax of {skipped['fixed']} of {len(starts)} pairs is its "
                               "tracks' drift")
        return None, info
    total = np.sum(costs, axis=0)
    i = int(np.argmin(total))
    depth_ratio = float(total[i] / np.median(total))
    info["depth_ratio"] = depth_ratio
    if i in (0, len(focals) - 1):
        info["reason"] = "the cost is lowest at the edge of the searched range"
        return None, info
    if depth_ratio > cfg.max_depth_ratio:
        info["reason"] = f"no clear minimum (lowest cost {depth_ratio:.2f} x the median)"
        return None, info
    # parabola through the three grid points around the minimum, in log focal
    x = np.log(focals[i - 1:i + 2])
    y = total[i - 1:i + 2]
    den = y[0] - 2 * y[1] + y[2]
    off = 0.5 * (y[0] - y[2]) / den if den > 0 else 0.0
    f = float(np.exp(x[1] + np.clip(off, -1, 1) * (x[2] - x[1])))
    per_pair = [float(focals[int(np.argmin(c))]) for c in costs]
    info.update({"focal_px": f, "fov_deg": float(np.rad2deg(2 * np.arctan2(w / 2.0, f))),
                 "per_pair_spread": float(np.std(np.log(per_pair)))})
    return f, info
