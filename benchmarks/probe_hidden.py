"""Where the dynamic ground-truth queries lose accuracy: their observations the result sees against those it
carries through hidden frames (``optim.hidden``), by the gap to the nearest seen frame, with the error of the
anchor (the seen frame the carry starts from) and of the carried step apart; an oracle row, the carry re-run
with each track's donors restricted to its own ground-truth object, which bounds what a better choice of donors
could gain; and a motion-model row, each track's own 3D velocity (a line fitted to its last / first
``VELOCITY_FRAMES`` seen positions) carried on past its last and before its first seen frame.

    .venv/bin/python benchmarks/probe_hidden.py bench_out/scenes/run_hard0_0 bench_out/scenes/hard0

RUN is a ``trackingworld run`` output folder, SCENE the synthetic scene it was run on (``bench_scenes.py`` keeps
both in its cache). Writes ``benchmarks/results/probe_hidden_<scene>.md`` (and prints it). Reads the ground truth
only to score and for the oracle row.
"""

from __future__ import annotations

import sys

import numpy as np

from _common import probe_inputs, query_pixels, scored_queries, write_results  # noqa: I001 (a sibling script module)
from trackingworld.config import OptimConfig
from trackingworld.eval.tracks import THRESHOLDS_M
from trackingworld.geometry import focal_length, invert_pose, transform
from trackingworld.optim.hidden import carry_hidden
from trackingworld.tracking2d.base import nearest_visible_frame

GAPS = ((1, 2), (3, 5), (6, 10), (11, 20), (21, 10**6))
VELOCITY_FRAMES = 10  # seen positions the motion-model row fits its line to (3 and 5 did worse on `hard` 0)


def own_velocity(xyz: np.ndarray, vis: np.ndarray, tracks: np.ndarray, n: int = VELOCITY_FRAMES) -> np.ndarray:
    """``xyz [N,T,3]`` with the frames of ``tracks`` after their last seen frame (before their first) moved on
    from it at the velocity of a line fitted to their last (first) ``n`` seen positions; the rest as given."""
    out = xyz.copy()
    frames = np.arange(vis.shape[1])
    for i in tracks:
        f = np.flatnonzero(vis[i])
        if len(f) < 2:
            continue
        for fit, beyond, s in ((f[-n:], frames > f[-1], f[-1]), (f[:n], frames < f[0], f[0])):
            if len(fit) < 2 or not beyond.any():
                continue
            v = np.polyfit(fit - fit.mean(), xyz[i, fit], 1)[0]  # [3] metres per frame
            out[i, beyond] = xyz[i, s] + (frames[beyond] - s)[:, None] * v
    return out


def accuracy(err: np.ndarray) -> float:
    """The world 3D accuracy (eval.tracks): mean over THRESHOLDS_M of the fraction of errors (metres) below each,
    in %; nan for none."""
    return 100 * float(np.mean([(err < th).mean() for th in THRESHOLDS_M])) if err.size else float("nan")


def main(argv=None) -> int:
    run, scene, res, gt = probe_inputs(__doc__, argv)
    cfg = OptimConfig()
    gd = gt["tracks_dynamic"]
    x, y = query_pixels(res)
    inst = gt["instance"][res.query_frame, y, x]  # each result track's object at its query pixel (oracle)
    dyn = np.flatnonzero(res.is_dynamic)
    # the carry as the pipeline runs it (motion scale from the result's own depths), and with object donors
    vis = res.visible
    few = dyn[:: max(1, len(dyn) // 4000)]
    z = transform(invert_pose(res.poses_c2w)[None], res.tracks_3d[few])[..., 2][vis[few]]
    scale = cfg.carry_motion_frames * float(np.median(z)) / focal_length(res.intrinsics) if z.size else 0.0

    def carried(groups):
        out = res.tracks_3d.copy()
        for g in groups:
            out[g] = carry_hidden(res.tracks_3d[g], vis[g], cfg.carry_k, cfg.carry_reach, uv=res.tracks_2d[g],
                                  motion_scale=scale, stat=cfg.carry_stat)
        return out

    rows = [("result as written", res.tracks_3d), ("carry re-run", carried([dyn])),
            ("carry, donors on the track's own object (oracle)", carried([dyn[inst[dyn] == i]
                                                                         for i in np.unique(inst[dyn])])),
            (f"the track's own velocity past its ends (last {VELOCITY_FRAMES} seen)",
             own_velocity(res.tracks_3d, vis, dyn))]
    lines = [f"# Hidden observations of the dynamic queries: `{scene.name}`", "",
             f"Command: `.venv/bin/python benchmarks/probe_hidden.py {run} {scene}`", "",
             "| carry | dynamic world acc | seen: acc (observations) | hidden: acc (observations) |",
             "|---|---|---|---|"]
    scored = [scored_queries(res, gt, xyz) for _, xyz in rows]
    ev = scored[0][3]  # the observations the metric scores, the same for every row
    for (name, _), (m, _, err, _) in zip(rows, scored, strict=True):
        seen, hid = ev & m.visible & gd[:, None], ev & ~m.visible & gd[:, None]
        lines.append(f"| {name} | {accuracy(err[ev & gd[:, None]]):.1f} | {accuracy(err[seen]):.1f} "
                     f"({seen.sum():,}) | {accuracy(err[hid]):.1f} ({hid.sum():,}) |")
    m, al, err, _ = scored[0]  # the result as written
    n, t = np.nonzero(ev & ~m.visible & gd[:, None])
    s = nearest_visible_frame(m.visible)[n, t]  # the anchor: nearest frame the result sees the query in
    gap = np.abs(t - s)
    step_err = np.linalg.norm((al[n, t] - al[n, s]) - (gt["tracks_xyz"][n, t] - gt["tracks_xyz"][n, s]), axis=-1)
    true_step = np.linalg.norm(gt["tracks_xyz"][n, t] - gt["tracks_xyz"][n, s], axis=-1)
    lines += ["", "Hidden observations of the result by their gap (frames) to the anchor:", "",
              "| gap | observations | acc | anchor acc | anchor median error [m] | step median error [m] | "
              "true step median [m] |", "|---|---|---|---|---|---|---|"]
    for lo, hi in GAPS:
        g = (gap >= lo) & (gap <= hi)
        if not g.any():
            continue
        lines.append(f"| {lo}-{hi if hi < 10**6 else ''} | {g.sum():,} | {accuracy(err[n, t][g]):.1f} | "
                     f"{accuracy(err[n, s][g]):.1f} | {np.median(err[n, s][g]):.3f} | {np.median(step_err[g]):.3f} | "
                     f"{np.median(true_step[g]):.3f} |")
    write_results(f"probe_hidden_{scene.name}", lines, {"lines": lines})
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
