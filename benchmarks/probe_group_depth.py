"""How each rigid group's depth follows the truth frame by frame, and whether its 2D tracks prefer its motion to
the true one: for every group of the result (``object_id`` / ``object_poses``), the ground-truth object most of
its tracks start on, and per solved frame the median ratio of its tracks' camera depth (after the Sim(3) of the camera
poses) to the true depth at their pixels, seen observations on that object only. One group of a rigid object has
one ratio in every frame when its motion is right up to the scale a monocular fit leaves free; a ratio that drifts
over the frames is a motion distorted in depth. The last columns compare the reprojection error of the group's
tracks on that object under the fitted positions and under the truth (the object's motion fitted to its
ground-truth query tracks, each track's point at the true depth of its query pixel): where the truth reprojects
worse, the 2D tracks themselves pull the fit off (stop 95: the 2D tracker drifts on movers, ``probe_drift.py``).

    .venv/bin/python benchmarks/probe_group_depth.py bench_out/scenes/run_hard22_0 bench_out/scenes/hard22

RUN is a ``trackingworld run`` output folder, SCENE the synthetic scene it was run on. Writes
``benchmarks/results/probe_group_depth_<scene>.md`` (and prints it).
"""

from __future__ import annotations

import sys

import numpy as np

from _common import probe_inputs, query_objects, query_pixels, write_results  # noqa: I001 (a sibling script module)
from trackingworld.eval.trajectory import sim3_from_poses
from trackingworld.geometry import (
    camera_depths,
    invert_pose,
    nearest_pixel,
    project,
    rigid_transform,
    transform,
    unproject,
)

MIN_OBS = 20  # seen observations of a group on its object a frame needs to get a ratio
MIN_QUERIES = 3  # ground-truth query tracks on an object its true motion is fitted to


def true_motion(gt: dict, obj: int) -> np.ndarray | None:
    """``[T,4,4]`` world-to-world motion of ground-truth object ``obj`` from frame 0 (the rigid fit of its
    ground-truth query tracks, which the synthetic scenes give in every frame), None with too few of them."""
    on = query_objects(gt) == obj
    if on.sum() < MIN_QUERIES:
        return None
    X = gt["tracks_xyz"][on]
    return np.stack([rigid_transform(X[:, 0], X[:, t]) for t in range(X.shape[1])])


def reprojection(res, gt: dict, members: np.ndarray, motion: np.ndarray | None):
    """(median px of the fitted positions, median px of the truth; None without a true motion) over the seen
    observations of ``members`` (tracks on the group's object)."""
    K, w2c = res.intrinsics, invert_pose(res.poses_c2w)
    q = res.query_frame[members]
    uvq = res.tracks_2d[members, q]
    _, H, W = gt["depth"].shape
    x, y = nearest_pixel(uvq, W, H)
    X0 = None  # each track's point on the true object at frame 0
    if motion is not None:
        world = transform(gt["poses_c2w"][q], unproject(uvq, gt["depth"][q, y, x], gt["K"]))
        X0 = transform(invert_pose(motion[q]), world)
    fit, truth = [], []
    for t in range(res.visible.shape[1]):
        v = np.flatnonzero(res.visible[members, t])
        if not len(v):
            continue
        p, _ = project(transform(w2c[t], res.tracks_3d[members[v], t]), K)
        fit.append(np.linalg.norm(p - res.tracks_2d[members[v], t], axis=1))
        if X0 is not None:
            p, _ = project(transform(invert_pose(gt["poses_c2w"][t]), transform(motion[t], X0[v])), gt["K"])
            truth.append(np.linalg.norm(p - res.tracks_2d[members[v], t], axis=1))
    return _median(fit), (_median(truth) if X0 is not None else None)


def _median(errors: list) -> float:
    """The median of the per-frame error arrays ``errors`` (px), NaN where there are none."""
    return float(np.median(np.concatenate(errors))) if errors else float("nan")


def main(argv=None) -> int:
    run, scene, res, gt = probe_inputs(__doc__, argv)
    if res.object_id is None or not len(res.object_poses):
        print(f"{run}: no rigid groups in this result")
        return 0
    T, H, W = gt["depth"].shape
    s = sim3_from_poses(res.poses_c2w, gt["poses_c2w"])["s"]
    x, y = query_pixels(res)
    start = gt["instance"][res.query_frame, y, x]
    lines = [f"# Rigid groups' depth frame by frame: `{scene.name}`", "",
             f"Command: `.venv/bin/python benchmarks/probe_group_depth.py {run} {scene}`", "",
             "Depth ratio: the group's tracks on its object, camera depth (after the Sim(3)) over the true depth, "
             f"median per frame with {MIN_OBS}+ seen observations; 2D: median reprojection error of those tracks.", "",
             "| group | tracks | object (share) | solved frames | ratio first / min / max / last frame | max / min "
             "| 2D fitted [px] | 2D truth [px] |", "|---|---|---|---|---|---|---|---|"]
    rows = []
    for g in range(len(res.object_poses)):
        members = np.flatnonzero(res.object_id == g)
        ids, counts = np.unique(start[members], return_counts=True)
        obj = int(ids[np.argmax(counts)])
        mine = members[start[members] == obj]
        solved = np.flatnonzero(np.isfinite(res.object_poses[g, :, 0, 0]))
        ratios = []
        for t in solved:
            v = mine[res.visible[mine, t]]
            if len(v) < MIN_OBS:
                continue
            xt, yt = nearest_pixel(res.tracks_2d[v, t], W, H)
            on = gt["instance"][t, yt, xt] == obj
            if on.sum() < MIN_OBS:
                continue
            z = s * camera_depths(res.tracks_3d[v[on], t][:, None], res.poses_c2w[t:t + 1])[:, 0]
            ratios.append((int(t), float(np.median(z / gt["depth"][t, yt[on], xt[on]]))))
        fit_px, truth_px = reprojection(res, gt, mine, true_motion(gt, obj))
        r = np.array([v for _, v in ratios])
        row = {"group": g, "tracks": int(len(members)), "object": obj, "share": float(counts.max() / len(members)),
               "frames": [int(solved.min()), int(solved.max())] if len(solved) else None,
               "ratios": ratios, "fit_px": fit_px, "truth_px": truth_px}
        rows.append(row)
        span = (f"{r[0]:.3f} / {r.min():.3f} / {r.max():.3f} / {r[-1]:.3f} (frames {ratios[0][0]}-{ratios[-1][0]})"
                if len(r) else "-")
        lines.append(f"| {g} | {len(members):,} | {obj} ({100 * row['share']:.0f}%) | "
                     f"{'-' if row['frames'] is None else '{}-{}'.format(*row['frames'])} | {span} | "
                     f"{r.max() / r.min() if len(r) else float('nan'):.3f} | {fit_px:.2f} | "
                     f"{'-' if truth_px is None else f'{truth_px:.2f}'} |")
    write_results(f"probe_group_depth_{scene.name}", lines, {"groups": rows})
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
