"""``trackingworld eval DIR --gt SCENE``: every metric of a result against a synthetic scene's ground truth,
with the raw depth prior's numbers on the same pixels beside the result's."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from trackingworld.errors import InputError
from trackingworld.eval.dense import (
    coverage,
    dense_flow,
    flow_metrics,
    label_metrics,
    static_deviation,
    track_depth_maps,
)
from trackingworld.eval.depth import depth_metrics
from trackingworld.eval.match import match_queries
from trackingworld.eval.tracks import tapvid_2d, tapvid_3d, world_accuracy
from trackingworld.eval.trajectory import apply_sim3, camera_metrics, sim3_from_poses, sim3_from_trajectories
from trackingworld.geometry import invert_pose, nearest_pixel, transform
from trackingworld.io.arrays import read_array, read_arrays
from trackingworld.io.atomic import write_json
from trackingworld.io.result import load_result


def load_gt(scene_dir: str | Path, T: int | None = None) -> dict:
    """Read ``SCENE/gt.npz`` (and the depth prior ``SCENE/input/depth.npy``), cut to the first T frames."""
    scene_dir = Path(scene_dir)
    path = scene_dir / "gt.npz" if scene_dir.is_dir() else scene_dir
    if not path.exists():
        raise InputError(f"{path}: no ground truth here (expected a folder written by `trackingworld synth`)")
    gt = read_arrays(path, "ground truth")
    prior = path.parent / "input" / "depth.npy"
    gt["prior_depth"] = read_array(prior, "depth prior", "depth") if prior.exists() else None
    T_gt = gt["poses_c2w"].shape[0]
    if T is not None and T != T_gt:
        if T > T_gt:
            raise InputError(f"{path}: ground truth has {T_gt} frames, result has {T}")
        for k in ("poses_c2w", "depth", "dynamic", "bg_mover", "instance", "prior_depth"):
            if gt.get(k) is not None:
                gt[k] = gt[k][:T]
        keep = gt["query_frame"] < T
        for k in ("tracks_xyz", "tracks_uv", "tracks_vis"):
            gt[k] = gt[k][keep][:, :T]
        for k in ("query_frame", "query_uv", "tracks_dynamic", "tracks_bg_mover"):
            gt[k] = gt[k][keep]
    return gt


def _to_cam(poses_c2w: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """World points [N,T,3] -> each frame's camera [N,T,3]."""
    w2c = invert_pose(poses_c2w.astype(np.float64))
    return transform(w2c[None], xyz.astype(np.float64))


def evaluate(result_dir: str | Path, scene_dir: str | Path) -> dict:
    res = load_result(result_dir)
    T, H, W = res.depth.shape
    gt = load_gt(scene_dir, T)
    if gt["depth"].shape[1:] != (H, W):
        raise InputError(f"{scene_dir}: ground truth is {gt['depth'].shape[2]}x{gt['depth'].shape[1]}, "
                         f"result is {W}x{H}")
    out: dict = {"frames": T, "size": [W, H], "tracks": res.num_tracks, "gt_scene": str(Path(scene_dir).resolve())}
    al = sim3_from_trajectories(res.poses_c2w, gt["poses_c2w"])
    out["camera"] = camera_metrics(res.poses_c2w, gt["poses_c2w"], al)

    # video depth, result vs raw prior on the same pixels
    prior = gt["prior_depth"]
    valid = gt["depth"] > 0
    out["video_depth"] = depth_metrics(res.depth, gt["depth"], valid)
    if prior is not None:
        out["video_depth_prior"] = depth_metrics(prior, gt["depth"], valid)
    # depth of the dense tracks (paper protocol)
    dmap, hit = track_depth_maps(res.tracks_2d, res.visible, res.tracks_3d, res.poses_c2w, H, W)
    out["track_depth"] = depth_metrics(dmap, gt["depth"], hit)
    if prior is not None:
        out["track_depth_prior"] = depth_metrics(prior, gt["depth"], hit)

    # ground-truth query tracks
    m = match_queries(res.tracks_2d, res.visible, res.tracks_3d, res.is_dynamic, gt["query_frame"],
                      gt["query_uv"])
    qf = gt["query_frame"]
    out["tracks_2d"] = tapvid_2d(m.uv, m.visible, gt["tracks_uv"], gt["tracks_vis"], qf, (W, H))
    out["tracks_2d"]["queries_matched"] = 100 * float(m.found.mean()) if m.found.size else None
    out["tapvid3d"] = tapvid_3d(_to_cam(res.poses_c2w, m.xyz), m.visible, _to_cam(gt["poses_c2w"], gt["tracks_xyz"]),
                                gt["tracks_vis"], qf, gt["K"], (W, H))
    # world frame: the Sim(3) of the whole camera poses (headline), and that of the centres alone (evo's ATE
    # alignment, ill-conditioned in the tilt about a nearly straight path), see trajectory.sim3_from_poses
    dyn = gt["tracks_dynamic"]
    for key, a in (("world_3d", sim3_from_poses(res.poses_c2w, gt["poses_c2w"])), ("world_3d_centres", al)):
        aligned = apply_sim3(a, m.xyz)
        out[key] = {
            "alignment": a["mode"], "scale": a["s"],
            "all": world_accuracy(aligned, gt["tracks_xyz"], gt["tracks_vis"], qf),
            "static": world_accuracy(aligned[~dyn], gt["tracks_xyz"][~dyn], gt["tracks_vis"][~dyn], qf[~dyn]),
            "dynamic": world_accuracy(aligned[dyn], gt["tracks_xyz"][dyn], gt["tracks_vis"][dyn], qf[dyn]),
        }
    out["coverage"] = coverage(res.tracks_2d, res.visible, H, W)
    src, dst = (int(v) for v in gt["flow_frames"])
    if src < T:
        pf, po = dense_flow(res.tracks_2d, res.visible, src, dst, H, W)
        out["flow"] = {"frames": [src, dst], **flow_metrics(pf, po, gt["flow"], gt["flow_occluded"])}
    # dynamic labels of the result's own tracks, judged at their query pixel
    x, y = nearest_pixel(res.tracks_2d[np.arange(res.num_tracks), res.query_frame], W, H)
    dev = static_deviation(res.tracks_2d, res.visible, res.query_frame, gt["depth"], gt["poses_c2w"], gt["K"])
    out["labels"] = label_metrics(res.is_dynamic, gt["dynamic"][res.query_frame, y, x],
                                  gt["bg_mover"][res.query_frame, y, x], dev)
    return out


ROWS = [
    ("ATE [m]", ("camera", "ate"), 4), ("ATE [% path]", ("camera", "ate_pct_path"), 2),
    ("RTE [m]", ("camera", "rte"), 4), ("RRE [deg]", ("camera", "rre"), 3),
    ("track depth AbsRel", ("track_depth", "abs_rel_depth"), 4),
    ("  prior, same px", ("track_depth_prior", "abs_rel_depth"), 4),
    ("track depth d<1.25", ("track_depth", "delta1_depth"), 3),
    ("video depth AbsRel", ("video_depth", "abs_rel_depth"), 4),
    ("  prior, same px", ("video_depth_prior", "abs_rel_depth"), 4),
    ("video depth AbsRel (disp)", ("video_depth", "abs_rel_disparity"), 4),
    ("  prior, same px", ("video_depth_prior", "abs_rel_disparity"), 4),
    ("world 3D acc [%]", ("world_3d", "all", "acc_avg"), 1),
    ("  static", ("world_3d", "static", "acc_avg"), 1),
    ("  dynamic", ("world_3d", "dynamic", "acc_avg"), 1),
    ("world 3D acc, centres [%]", ("world_3d_centres", "all", "acc_avg"), 1),
    ("  static", ("world_3d_centres", "static", "acc_avg"), 1),
    ("  dynamic", ("world_3d_centres", "dynamic", "acc_avg"), 1),
    ("TAPVid-3D AJ", ("tapvid3d", "aj"), 1), ("TAPVid-3D APD", ("tapvid3d", "apd_3d"), 1),
    ("TAPVid-3D OA", ("tapvid3d", "oa"), 1),
    ("2D delta_avg", ("tracks_2d", "delta_avg"), 1), ("2D occlusion acc", ("tracks_2d", "occlusion_acc"), 1),
    ("flow EPE [px]", ("flow", "epe"), 2), ("flow occ IoU", ("flow", "occ_iou"), 3),
    ("coverage (track within 1 px)", ("coverage", "coverage_r1"), 3),
    ("coverage (rounded hit)", ("coverage", "coverage"), 3),
    ("dynamic recall [%]", ("labels", "dynamic_recall"), 1),
    ("dynamic precision [%]", ("labels", "dynamic_precision"), 1),
    ("static kept static [%]", ("labels", "static_kept_static"), 1),
    ("bg-mover recall [%]", ("labels", "bg_mover_recall"), 1),
    ("static within 2 px [%]", ("labels", "static_consistent_pct"), 1),
    ("  of those kept static [%]", ("labels", "static_kept_static_consistent"), 1),
    ("bg-movers moved 8+ px [%]", ("labels", "bg_mover_moved_pct"), 1),
    ("  of those recalled [%]", ("labels", "bg_mover_recall_moved"), 1),
]


def _get(d: dict, path):
    for k in path:
        if not isinstance(d, dict) or k not in d or d[k] is None:
            return None
        d = d[k]
    return d


def format_table(columns: dict[str, dict]) -> str:
    """Plain-text table, one column per named metrics dict."""
    names = list(columns)
    width = max(12, *(len(n) + 2 for n in names))
    lw = max(len(label) for label, _, _ in ROWS) + 1
    lines = ["metric".ljust(lw) + "".join(n.rjust(width) for n in names)]
    lines.append("-" * len(lines[0]))
    for label, path, nd in ROWS:
        vals = []
        for n in names:
            v = _get(columns[n], path)
            vals.append(("-" if v is None else f"{v:.{nd}f}").rjust(width))
        lines.append(label.ljust(lw) + "".join(vals))
    return "\n".join(lines)


def evaluate_to_file(result_dir: str | Path, scene_dir: str | Path) -> dict:
    metrics = evaluate(result_dir, scene_dir)
    write_json(Path(result_dir) / "metrics.json", metrics)
    return metrics


def load_metrics(result_dir: str | Path) -> dict:
    return json.loads((Path(result_dir) / "metrics.json").read_text())
