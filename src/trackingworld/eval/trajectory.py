"""Camera metrics with ``evo``: ATE (APE translation, Sim(3) Umeyama with scale, RMSE) and RTE / RRE
(RPE over consecutive frames, translation metres and rotation degrees, RMSE) after the same alignment."""

from __future__ import annotations

import copy

import numpy as np
from evo.core import metrics
from evo.core.geometry import GeometryException
from evo.core.trajectory import PoseTrajectory3D

MIN_SPREAD = 1e-6  # metres: below this a trajectory's positions are treated as a single point


def _traj(poses: np.ndarray) -> PoseTrajectory3D:
    return PoseTrajectory3D(poses_se3=[np.asarray(p, np.float64) for p in poses],
                            timestamps=np.arange(len(poses), dtype=np.float64))


def sim3_from_trajectories(est_c2w: np.ndarray, gt_c2w: np.ndarray) -> dict:
    """Alignment mapping the estimate's world into the ground truth's: ``x_gt = s R x_est + t``.

    Umeyama Sim(3) on the camera centres (as evo computes it). Where either trajectory is (nearly) a
    single point, Umeyama is degenerate: then the first cameras are aligned rigidly with scale 1 and
    ``mode`` says so.
    """
    spread_est = np.linalg.norm(est_c2w[:, :3, 3] - est_c2w[:, :3, 3].mean(0), axis=1).max()
    spread_gt = np.linalg.norm(gt_c2w[:, :3, 3] - gt_c2w[:, :3, 3].mean(0), axis=1).max()
    if spread_est > MIN_SPREAD and spread_gt > MIN_SPREAD and len(est_c2w) >= 3:
        est = copy.deepcopy(_traj(est_c2w))
        try:
            R, t, s = est.align(_traj(gt_c2w), correct_scale=True)
        except GeometryException:  # e.g. collinear positions
            s = np.nan
        if np.isfinite(s) and s > 0:
            return {"s": float(s), "R": np.asarray(R), "t": np.asarray(t), "mode": "sim3_umeyama"}
    A = gt_c2w[0] @ np.linalg.inv(est_c2w[0])
    return {"s": 1.0, "R": A[:3, :3], "t": A[:3, 3], "mode": "first_frame_se3"}


def sim3_from_poses(est_c2w: np.ndarray, gt_c2w: np.ndarray) -> dict:
    """Alignment ``x_gt = s R x_est + t`` from whole camera poses: R is the rotation nearest (chordal mean) to
    the per-frame ``R_gt R_est^T``, then s and t by least squares on the camera centres given R.

    Umeyama on the centres alone leaves the rotation about a nearly straight path to the path's small
    curvature (a forward-moving camera on a planar path: the tilt about the path is set by centimetres of
    sideways motion), and a degree of tilt there moves a point 7 m away by 12 cm; the orientations fix it.
    ``mode`` is ``sim3_poses``; the scale is 1 when the estimate's centres do not spread."""
    Re, Rg = est_c2w[:, :3, :3].astype(np.float64), gt_c2w[:, :3, :3].astype(np.float64)
    U, _, Vt = np.linalg.svd(np.einsum("tij,tkj->ik", Rg, Re))  # sum over frames of R_gt R_est^T
    R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    ce, cg = est_c2w[:, :3, 3].astype(np.float64), gt_c2w[:, :3, 3].astype(np.float64)
    de, dg = ce - ce.mean(0), cg - cg.mean(0)
    var = float((de**2).sum())
    s = float(np.einsum("ti,ti->", dg, de @ R.T) / var) if var > MIN_SPREAD**2 * len(ce) else 1.0
    if not np.isfinite(s) or s <= 0:
        s = 1.0
    return {"s": s, "R": R, "t": cg.mean(0) - s * R @ ce.mean(0), "mode": "sim3_poses"}


def apply_sim3(al: dict, poses_or_pts: np.ndarray) -> np.ndarray:
    """Apply an alignment to points ``[...,3]`` or to c2w poses ``[T,4,4]``."""
    if poses_or_pts.shape[-2:] == (4, 4):
        out = np.array(poses_or_pts, np.float64).copy()
        out[:, :3, :3] = al["R"] @ out[:, :3, :3]
        out[:, :3, 3] = al["s"] * out[:, :3, 3] @ al["R"].T + al["t"]
        return out
    return al["s"] * poses_or_pts @ al["R"].T + al["t"]


def camera_metrics(est_c2w: np.ndarray, gt_c2w: np.ndarray, al: dict | None = None) -> dict:
    """ATE [m], RTE [m], RRE [deg] as in MonST3R / LEAP-VO / Uni4D, plus the alignment used
    (``al`` from :func:`sim3_from_trajectories`, computed here when not given)."""
    al = al or sim3_from_trajectories(est_c2w, gt_c2w)
    est = _traj(apply_sim3(al, est_c2w))
    gt = _traj(gt_c2w)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((gt, est))
    out = {"ate": float(ape.get_statistic(metrics.StatisticsType.rmse))}
    for key, rel in (("rte", metrics.PoseRelation.translation_part),
                     ("rre", metrics.PoseRelation.rotation_angle_deg)):
        rpe = metrics.RPE(rel, delta=1, delta_unit=metrics.Unit.frames, all_pairs=True)
        rpe.process_data((gt, est))
        out[key] = float(rpe.get_statistic(metrics.StatisticsType.rmse))
    path = np.linalg.norm(np.diff(gt_c2w[:, :3, 3], axis=0), axis=1).sum()
    out["gt_path_length"] = float(path)
    out["ate_pct_path"] = float(100 * out["ate"] / path) if path > MIN_SPREAD else None
    out["alignment"] = al["mode"]
    out["scale"] = al["s"]
    if al["mode"] != "sim3_umeyama":
        out["note"] = "trajectory (nearly) static: Sim(3) degenerate, aligned on the first frame"
    return out
