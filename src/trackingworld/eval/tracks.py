"""Track metrics: TAP-Vid 2D (delta_avg, occlusion accuracy), TAPVid-3D (AJ, APD_3D, OA) and
world-frame 3D accuracy. Evaluation points exclude each track's query frame, as in tapnet."""

from __future__ import annotations

import numpy as np

THRESHOLDS_PX = (1, 2, 4, 8, 16)
THRESHOLDS_M = (0.05, 0.10, 0.20, 0.40, 0.80)


def eval_points(query_frame: np.ndarray, T: int) -> np.ndarray:
    """``[N,T]`` bool: the frames a track is scored in, every frame but its query frame ``query_frame [N]``."""
    return np.arange(T)[None, :] != query_frame[:, None]


def tapvid_2d(pred_uv, pred_vis, gt_uv, gt_vis, query_frame, size_wh, eval_size=(256, 256)) -> dict:
    """delta_avg (%) of gt-visible points and occlusion accuracy (%), coordinates scaled to 256x256."""
    N, T = gt_vis.shape
    ev = eval_points(query_frame, T)
    sc = np.array([eval_size[0] / size_wh[0], eval_size[1] / size_wh[1]])
    err = np.linalg.norm((pred_uv - gt_uv) * sc, axis=-1)
    m = gt_vis & ev
    fracs = [float(((err < th) & m).sum() / max(m.sum(), 1)) for th in THRESHOLDS_PX]
    oa = float(((pred_vis == gt_vis) & ev).sum() / max(ev.sum(), 1))
    return {"delta_avg": 100 * float(np.mean(fracs)), "occlusion_acc": 100 * oa,
            **{f"delta_{t}px": 100 * f for t, f in zip(THRESHOLDS_PX, fracs, strict=True)}}


def tapvid_3d(pred_xyz_cam, pred_vis, gt_xyz_cam, gt_vis, query_frame, K, size_wh, short_side=256) -> dict:
    """AJ, APD_3D, OA (%) in camera coordinates with global median scaling, as tapnet computes them.

    Thresholds {1,2,4,8,16} px become metric radii ``thr * z_gt / sqrt(fx*fy)`` with intrinsics rescaled
    so that the image's short side is 256 px.
    """
    N, T = gt_vis.shape
    ev = eval_points(query_frame, T)
    both = gt_vis & pred_vis
    gn = np.linalg.norm(gt_xyz_cam, axis=-1)
    pn = np.linalg.norm(pred_xyz_cam, axis=-1)
    scale = np.median(gn[both]) / max(np.median(pn[both]), 1e-9) if both.any() else 1.0
    pred = pred_xyz_cam * scale
    f = short_side / min(size_wh)
    focal = np.sqrt(K[0, 0] * f * K[1, 1] * f)
    mult = gt_xyz_cam[..., 2] / focal
    dist = np.linalg.norm(pred - gt_xyz_cam, axis=-1)
    aj, apd = [], []
    for th in THRESHOLDS_PX:
        within = dist < th * mult
        tp = (within & gt_vis & pred_vis & ev).sum()
        gt_pos = (gt_vis & ev).sum()
        fp = (pred_vis & (~gt_vis | ~within) & ev).sum()
        aj.append(tp / max(gt_pos + fp, 1))
        apd.append((within & gt_vis & ev).sum() / max(gt_pos, 1))
    oa = ((pred_vis == gt_vis) & ev).sum() / max(ev.sum(), 1)
    return {"aj": 100 * float(np.mean(aj)), "apd_3d": 100 * float(np.mean(apd)), "oa": 100 * float(oa),
            "median_scale": float(scale)}


def world_accuracy(pred_xyz_world_aligned, gt_xyz, gt_vis, query_frame) -> dict:
    """Fraction (%) of gt-visible points within 5/10/20/40/80 cm in the world frame, and their mean."""
    ev = eval_points(query_frame, gt_vis.shape[1]) & gt_vis
    err = np.linalg.norm(pred_xyz_world_aligned - gt_xyz, axis=-1)[ev]
    if err.size == 0:
        return {"n_points": 0}
    fr = [float((err < th).mean()) for th in THRESHOLDS_M]
    out = {"acc_avg": 100 * float(np.mean(fr)), "median_err_m": float(np.median(err)), "n_points": int(err.size)}
    out.update({f"within_{int(th * 100)}cm": 100 * f for th, f in zip(THRESHOLDS_M, fr, strict=True)})
    return out
