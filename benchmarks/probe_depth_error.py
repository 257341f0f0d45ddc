"""Where the world error of the ground-truth queries lies: along the camera's ray (depth) or across it, and, for
each moving object, how its depth follows the truth and the depth prior frame by frame.

    .venv/bin/python benchmarks/probe_depth_error.py bench_out/scenes/run_hard0_0 bench_out/scenes/hard0

RUN is a ``trackingworld run`` output folder, SCENE the synthetic scene it was run on (``bench_scenes.py`` keeps
both in its cache). The queries are read through the metric's own matching (``eval.match``) and the Sim(3) of
the camera poses (``eval.trajectory.sim3_from_poses``), so the errors are the world 3D accuracy's.

- Static queries, by their depth at the query frame: the error along the ground-truth camera's ray (as a
  fraction of the depth, its median size and signed mean: a band that is too far or too near as a whole) and
  across it.
- Dynamic queries, by the ground-truth object under their query pixel: accuracy, and the median ratio of the
  result's camera depth to the truth's in each frame, beside the raw prior's ratio at the same pixels
  (``input/depth.npy``). A rigid group placed with the wrong scale has a steady ratio away from 1; one whose
  depth follows the prior's frame-to-frame error has a ratio that wanders with the prior's.

Writes ``benchmarks/results/probe_depth_error_<scene>.md`` (and prints it).
"""

from __future__ import annotations

import sys

import numpy as np

from _common import probe_inputs, query_objects, scored_queries, write_results  # noqa: I001 (a sibling script module)
from probe_hidden import accuracy
from trackingworld.geometry import invert_pose, nearest_pixel, transform

# (label, from, to) metres of the static queries' rows
DEPTH_BANDS_M = (("all", 0.0, np.inf), ("0-3", 0.0, 3.0), ("3-5", 3.0, 5.0), ("5-8", 5.0, 8.0), ("8-", 8.0, np.inf))
FRAME_STEP = 4  # frames between the rows of the per-frame ratios


def ray_split(pred: np.ndarray, true: np.ndarray, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World points ``pred``, ``true [n,3]`` (metres) seen from camera centres ``centres [n,3]`` -> (the error along
    the ray from the centre to ``true``, signed, positive beyond it [n]; the error across it [n]; the depth along
    the ray [n]), metres."""
    ray = true - centres
    r = np.linalg.norm(ray, axis=1)
    ray = ray / np.maximum(r, 1e-12)[:, None]
    e = pred - true
    along = (e * ray).sum(1)
    return along, np.linalg.norm(e - along[:, None] * ray, axis=1), r


def main(argv=None) -> int:
    run, scene, res, gt = probe_inputs(__doc__, argv)
    qf, n = gt["query_frame"], len(gt["query_frame"])
    dyn = gt["tracks_dynamic"].astype(bool)
    _, pred, err, ev = scored_queries(res, gt)  # pred [n,T,3] in the truth's world frame
    true, poses = gt["tracks_xyz"], gt["poses_c2w"]
    lines = [f"# World error along and across the ray: `{scene.name}`", "",
             f"Command: `.venv/bin/python benchmarks/probe_depth_error.py {run} {scene}`", "",
             f"World 3D accuracy: static {accuracy(err[ev & ~dyn[:, None]]):.2f}, dynamic "
             f"{accuracy(err[ev & dyn[:, None]]):.2f}.", "",
             "Static queries at their query frame, by depth:", "",
             "| depth [m] | queries | along the ray: median abs / depth [%] | signed mean / depth [%] | "
             "across: median [cm] | along: median abs [cm] |", "|---|---|---|---|---|---|"]
    st = np.flatnonzero(~dyn)
    along, across, depth = ray_split(pred[st, qf[st]], true[st, qf[st]], poses[qf[st], :3, 3])
    data = {"static": [], "objects": []}
    for band, lo, hi in DEPTH_BANDS_M:
        b = (depth >= lo) & (depth < hi) & np.isfinite(along)
        if not b.any():
            continue
        row = [int(b.sum()), 100 * float(np.median(np.abs(along[b]) / depth[b])),
               100 * float(np.mean(along[b] / depth[b])), 100 * float(np.median(across[b])),
               100 * float(np.median(np.abs(along[b])))]
        data["static"].append([lo, hi, *row])
        lines.append(f"| {band} | {row[0]} | {row[1]:.2f} | {row[2]:+.2f} | {row[3]:.1f} | {row[4]:.1f} |")

    T, H, W = gt["depth"].shape
    prior = np.load(scene / "input" / "depth.npy")
    obj = query_objects(gt)
    w2c = invert_pose(poses)
    z_pred = transform(w2c[None], pred)[..., 2]  # [n,T] camera depths in the truth's cameras
    z_true = transform(w2c[None], true)[..., 2]
    ux, uy = nearest_pixel(gt["tracks_uv"].reshape(-1, 2), W, H)
    z_prior = prior[np.repeat(np.arange(T)[None], n, 0).reshape(-1), uy, ux].reshape(n, T)
    lines += ["", "Dynamic queries by object (the instance under the query pixel): result / true and prior / true "
              "camera depth, the median over the object's scored queries in every "
              f"{FRAME_STEP}th frame:", "",
              "| object | missed by the masks | queries | world acc | median error [cm] | frame: result / prior |",
              "|---|---|---|---|---|---|"]
    for o in np.unique(obj[dyn]):
        q = np.flatnonzero(dyn & (obj == o))
        s = ev[q]
        if not s.any():
            continue
        cells, ratios = [], []
        for t in range(0, T, FRAME_STEP):
            k = q[s[:, t]]
            if not len(k):
                continue
            rp, rq = float(np.median(z_pred[k, t] / z_true[k, t])), float(np.median(z_prior[k, t] / z_true[k, t]))
            cells.append(f"{t}: {rp:.3f} / {rq:.3f}")
            ratios.append([t, rp, rq])
        missed = bool(gt["tracks_bg_mover"][q].mean() > 0.5)
        e = err[q][s]
        data["objects"].append({"object": int(o), "missed": missed, "queries": len(q), "acc": accuracy(e),
                                "ratios": ratios})
        lines.append(f"| {o} | {'yes' if missed else 'no'} | {len(q)} | {accuracy(e):.1f} | "
                     f"{100 * np.median(e):.1f} | {'; '.join(cells)} |")
    write_results(f"probe_depth_error_{scene.name}", lines, data)
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
