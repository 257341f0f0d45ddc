"""Benchmark of the world-centric optimiser (issue 4), run on demand:
``.venv/bin/python benchmarks/bench_optim.py [--preset default] [--quick]``.

On one synthetic scene, with the same dense 2D tracks for every row (tracked once, then passed as a tracks
file), runs: the full method with the structured solver (default), the same with the paper's Adam schedule
(``--solver adam``), each ablation switch of the paper's table, the "w/o T.E.F" tracks, and the camera-centric
baseline. Reports ATE / RTE / RRE, track and video depth Abs Rel beside the raw prior on the same pixels,
world 3D accuracy (all / dynamic), labels, and the optimisation time of each row. Writes
``benchmarks/results/optim_<preset>.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from _common import OPT_STAGES, fmt, md_table_start, run_and_evaluate, scratch_dir, tracks_file, write_results  # noqa: I001 (a sibling script module)
from trackingworld.config import InputConfig, OptimConfig, RunConfig, Track2DConfig
from trackingworld.io.frames import read_frames
from trackingworld.synth import render_and_write

ROWS = {
    "full (lm solver, default)": ("trackingworld", {}, False),
    "full (adam, paper schedule)": ("trackingworld", {"solver": "adam"}, False),
    "w/o T.E.F": ("trackingworld", {}, True),
    "w/o pose-init": ("trackingworld", {"no_pose_init": True}, False),
    "w/o D.O.T": ("trackingworld", {"no_dynamic_opt": True}, False),
    "w/o N_inliers": ("trackingworld", {"no_inliers": True}, False),
    "w/o O_static": ("trackingworld", {"no_offsets": True}, False),
    "w/o L_dc": ("trackingworld", {"no_depth_consistency": True}, False),
    "dc on metres (paper as written)": ("trackingworld", {"dc_space": "metres"}, False),
    "every static track optimised (no speed-up)": ("trackingworld", {"downsample_cell": 0}, False),
    "baseline (camera-centric)": ("baseline", {}, False),
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--preset", default="default")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="skip the Adam row (minutes)")
    ap.add_argument("--keep", action="store_true", help="keep the scratch folder of scenes, tracks and runs")
    a = ap.parse_args(argv)
    work = scratch_dir("bench_optim_", a.keep)
    scene = render_and_write(work / "scene", a.preset, a.seed)
    inp = scene / "input"
    frames, _ = read_frames(str(inp / "frames"))
    tracks = {ff: tracks_file(scene, work / ("tracks_first.npz" if ff else "tracks.npz"), ff) for ff in (False, True)}
    results = {}
    for name, (method, opts, tef_off) in ROWS.items():
        if a.quick and opts.get("solver") == "adam":
            continue
        cfg = RunConfig(method=method, inputs=InputConfig(
            input=str(inp / "frames"), depth=str(inp / "depth.npy"), masks=str(inp / "masks"),
            intrinsics=str(inp / "intrinsics.txt")),
            track2d=Track2DConfig(tracker="file", tracks_file=str(tracks[tef_off])),
            optim=OptimConfig(verbose=False, **opts))
        r = run_and_evaluate(cfg, work / f"run{len(results)}", scene, name)
        results[name] = {**r, "optim_s": sum(r["timings"].get(k, 0.0) for k in OPT_STAGES)}
    write(results, a.preset + (" --quick" if a.quick else ""), frames.shape)
    return 0


def write(results: dict, preset: str, shape) -> None:
    head = ("| configuration | ATE [% path] | RTE [m] | RRE [deg] | track depth AbsRel (prior) | "
            "video depth AbsRel (prior) | world 3D acc all / dyn | static kept [%] | bg-mover recall [%] | "
            "optimisation [s] |")
    scene = preset.split()[0]
    lines = md_table_start(
        f"# World-centric optimiser on the `{scene}` scene ({shape[0]} frames, {shape[2]}x{shape[1]})",
        f"Command: `.venv/bin/python benchmarks/bench_optim.py --preset {preset}`", head)
    for name, r in results.items():
        m = r["metrics"]
        c, td, vd, w, lab = m["camera"], m["track_depth"], m["video_depth"], m["world_3d"], m["labels"]
        lines.append(
            f"| {name} | {fmt(c['ate_pct_path'], 2)} | {fmt(c['rte'], 4)} | {fmt(c['rre'], 3)} | "
            f"{fmt(td['abs_rel_depth'], 4)} ({fmt(m['track_depth_prior']['abs_rel_depth'], 4)}) | "
            f"{fmt(vd['abs_rel_depth'], 4)} ({fmt(m['video_depth_prior']['abs_rel_depth'], 4)}) | "
            f"{fmt(w['all']['acc_avg'], 1)} / {fmt(w['dynamic']['acc_avg'], 1)} | "
            f"{fmt(lab['static_kept_static'], 1)} | {fmt(lab['bg_mover_recall'], 1)} | {r['optim_s']:.1f} |")
    write_results(f"optim_{scene}", lines, {k: {"metrics": v["metrics"], "timings": v["timings"], "wall_s": v["wall_s"]}
                                          for k, v in results.items()})


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
