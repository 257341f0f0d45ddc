"""Metrics on the dense output: coverage, long-range flow, the dense-track depth protocol, labels."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from trackingworld.geometry import invert_pose, nearest_pixel, project, transform, unproject
from trackingworld.tracking2d.dense import splat_coverage


def coverage(tracks_2d: np.ndarray, visible: np.ndarray, H: int, W: int) -> dict:
    """Fraction of the pixels of each frame hit by a visible track (rounded position), averaged over frames;
    ``coverage_r1``: the fraction with a visible track within 1 px (the tracker's covering rule)."""
    T = visible.shape[1]
    hit = np.zeros((T, H, W), bool)
    near = np.zeros((T, H, W), bool)
    splat_coverage(hit, tracks_2d, visible, 0.0)
    splat_coverage(near, tracks_2d, visible, 1.0)
    per = hit.reshape(T, -1).mean(1)
    return {"coverage": float(per.mean()), "coverage_min": float(per.min()),
            "coverage_r1": float(near.mean()), "coverage_per_frame": per.tolist()}


def dense_flow(tracks_2d, visible, src: int, dst: int, H: int, W: int):
    """Flow ``[H,W,2]`` from frame src to dst and predicted occlusion ``[H,W]``, read from the tracks
    visible in ``src`` (nearest track per pixel, its displacement carried over)."""
    cand = np.flatnonzero(visible[:, src])
    ys, xs = np.mgrid[0:H, 0:W]
    pix = np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float64)
    if cand.size == 0:
        return np.zeros((H, W, 2)), np.ones((H, W), bool)
    _, j = cKDTree(tracks_2d[cand, src]).query(pix, k=1)
    idx = cand[j]
    flow = tracks_2d[idx, dst] - tracks_2d[idx, src]
    return flow.reshape(H, W, 2), ~visible[idx, dst].reshape(H, W)


def flow_metrics(pred_flow, pred_occ, gt_flow, gt_occ) -> dict:
    epe = float(np.linalg.norm(pred_flow - gt_flow, axis=-1).mean())
    inter = (pred_occ & gt_occ).sum()
    union = (pred_occ | gt_occ).sum()
    return {"epe": epe, "occ_iou": float(inter / union) if union else 1.0}


def track_depth_maps(tracks_2d, visible, tracks_3d, poses_c2w, H: int, W: int):
    """The paper's protocol: project every visible track into its frame (camera depth from the world
    position and pose, pixel = rounded 2D position), keep the smaller depth per pixel.
    Returns depth ``[T,H,W]`` (0 where no track) and the hit mask."""
    T = visible.shape[1]
    out = np.full((T, H, W), np.inf, np.float32)
    for t in range(T):
        v = visible[:, t]
        z = transform(invert_pose(poses_c2w[t].astype(np.float64)), tracks_3d[v, t].astype(np.float64))[:, 2]
        xy = np.round(tracks_2d[v, t]).astype(np.int64)
        ok = (xy[:, 0] >= 0) & (xy[:, 0] < W) & (xy[:, 1] >= 0) & (xy[:, 1] < H) & (z > 0)
        np.minimum.at(out[t].reshape(-1), xy[ok, 1] * W + xy[ok, 0], z[ok].astype(np.float32))
    hit = np.isfinite(out)
    return np.where(hit, out, 0.0), hit


CONSISTENT_PX = 2.0  # a static track within this of a static point's projection in every visible frame
MOVED_PX = 8.0  # a mover's track at least this far from a static point's projection in some visible frame


def static_points(tracks_2d: np.ndarray, query_frame: np.ndarray, depth: np.ndarray, poses_c2w: np.ndarray,
                  K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ground-truth 3D point under each track's query pixel (``tracks_2d [N,T,2]`` at ``query_frame [N]``,
    ``depth [T,H,W]``, ``poses_c2w``, ``K``): (world points ``[N,3]`` metres, the query pixels' depth ``[N]``, 0
    where there is none)."""
    N = len(query_frame)
    H, W = depth.shape[1:]
    q = tracks_2d[np.arange(N), query_frame].astype(np.float64)
    x, y = nearest_pixel(q, W, H)
    z = depth[query_frame, y, x].astype(np.float64)
    return transform(poses_c2w[query_frame], unproject(q, np.maximum(z, 1e-6), K)), z


def static_deviation(tracks_2d: np.ndarray, visible: np.ndarray, query_frame: np.ndarray, depth: np.ndarray,
                     poses_c2w: np.ndarray, K: np.ndarray) -> np.ndarray:
    """[N] px: how far each track (``tracks_2d [N,T,2]``, ``visible [N,T]``) strays, over its visible frames,
    from the projection of the ground-truth 3D point under its query pixel (:func:`static_points`) held static.
    Small for a static point tracked well; large for a mover or a track that slipped off its point. NaN where the
    query pixel has no depth."""
    X, z = static_points(tracks_2d, query_frame, depth, poses_c2w, K)
    out = np.zeros(len(X))
    w2c = invert_pose(poses_c2w)
    for t in range(visible.shape[1]):  # frame by frame: a dense result holds millions of tracks
        v = np.flatnonzero(visible[:, t])
        uv, _ = project(transform(w2c[t], X[v]), K)
        out[v] = np.maximum(out[v], np.linalg.norm(uv - tracks_2d[v, t], axis=-1))
    return np.where(z > 0, out, np.nan)


def label_metrics(pred_dyn: np.ndarray, gt_dyn: np.ndarray, gt_bg: np.ndarray,
                  deviation: np.ndarray | None = None) -> dict:
    """Recall / precision (%) of the dynamic label, static kept static, and recall on the movers the
    coarse masks missed, reported on their own. With ``deviation`` ([N] px, :func:`static_deviation`) the
    labeller is also judged apart from the 2D tracker: static kept static among the static tracks that stay
    within ``CONSISTENT_PX`` of a static point (a slipped track is rightly not static), and missed-mover recall
    among the tracks that moved ``MOVED_PX`` or more (one that did not move is indistinguishable from static)."""
    tp = (pred_dyn & gt_dyn).sum()
    out = {
        "dynamic_recall": 100 * float(tp / max(gt_dyn.sum(), 1)),
        "dynamic_precision": 100 * float(tp / max(pred_dyn.sum(), 1)),
        "static_kept_static": 100 * float((~pred_dyn & ~gt_dyn).sum() / max((~gt_dyn).sum(), 1)),
        "n_tracks_gt_dynamic": int(gt_dyn.sum()),
        "n_tracks_bg_mover": int(gt_bg.sum()),
    }
    out["bg_mover_recall"] = 100 * float((pred_dyn & gt_bg).sum() / gt_bg.sum()) if gt_bg.any() else None
    if deviation is not None:
        ok = np.isfinite(deviation)
        cons = ok & ~gt_dyn & (deviation <= CONSISTENT_PX)
        moved = ok & gt_bg & (deviation >= MOVED_PX)
        out["static_consistent_pct"] = 100 * float(cons.sum() / max((ok & ~gt_dyn).sum(), 1))
        out["static_kept_static_consistent"] = 100 * float((~pred_dyn & cons).sum() / max(cons.sum(), 1))
        out["bg_mover_moved_pct"] = 100 * float(moved.sum() / gt_bg.sum()) if gt_bg.any() else None
        out["bg_mover_recall_moved"] = 100 * float((pred_dyn & moved).sum() / moved.sum()) if moved.any() else None
    return out
