"""What the intrinsics cost when none are given: synthetic scenes rendered at several fields of view, run with the
true intrinsics, with the assumed 60 deg, and self-calibrated from the video (priors.focal), each with the focal
length held fixed and refined in stage 2 (``--refine-focal``); depth and masks given, and once more with nothing
but the video.

    .venv/bin/python benchmarks/bench_focal.py      # writes benchmarks/results/focal_default.md

Each scene's dense 2D tracks are computed once and shared by its rows.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from _common import fmt, md_table_start, run_and_evaluate, scratch_dir, tracks_file, write_results  # noqa: I001 (a sibling script module)
from trackingworld.config import InputConfig, OptimConfig, RunConfig, Track2DConfig
from trackingworld.synth import render_and_write
from trackingworld.synth.scene import PRESETS

# row: (depth and masks given?, intrinsics given?, self-calibrate?, stage-2 focal refinement)
ROWS = {
    "given intrinsics": (True, True, False, "off"),
    "assumed 60 deg, fixed": (True, False, False, "off"),
    "assumed 60 deg, refined": (True, False, False, "on"),
    "self-calibrated, fixed": (True, False, True, "off"),
    "self-calibrated, refined": (True, False, True, "on"),
    "video only, assumed 60 deg, fixed": (False, False, False, "off"),
    "video only, assumed 60 deg, refined": (False, False, False, "on"),
    "video only, self-calibrated, fixed": (False, False, True, "off"),
    "video only, self-calibrated, refined": (False, False, True, "on"),
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--preset", default="default", choices=sorted(PRESETS))
    ap.add_argument("--fovs", type=float, nargs="+", default=[40.0, 60.0, 90.0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep", action="store_true", help="keep the scratch folder of scenes, tracks and runs")
    a = ap.parse_args(argv)
    work = scratch_dir("bench_focal_", a.keep)
    results: dict = {}
    for fov in a.fovs:
        scene = render_and_write(work / f"scene{fov:g}", a.preset, a.seed, fov_deg=fov, verbose=False)
        inp = scene / "input"
        tracks = tracks_file(scene, work / f"tracks{fov:g}.npz")
        for name, (priors_given, k_given, selfcal, refine) in ROWS.items():
            kw = ({"depth": str(inp / "depth.npy"), "masks": str(inp / "masks")} if priors_given else {})
            if k_given:
                kw["intrinsics"] = str(inp / "intrinsics.txt")
            cfg = RunConfig(inputs=InputConfig(input=str(inp / "frames"), self_calibrate=selfcal, **kw),
                            track2d=Track2DConfig(tracker="file", tracks_file=str(tracks)),
                            optim=OptimConfig(verbose=False, refine_focal=refine))
            out = work / f"run{fov:g}_{len(results)}"
            r = run_and_evaluate(cfg, out, scene, f"fov {fov:g}: {name}")
            z = np.load(out / "result.npz")
            W = z["depth"].shape[2]
            r["fov_used_deg"] = float(np.rad2deg(2 * np.arctan2(W / 2, z["intrinsics"][0, 0])))
            r["priors"] = json.loads((out / "priors.json").read_text())
            results[f"{fov:g}|{name}"] = r
    lines = md_table_start(
        f"# Intrinsics when none are given (`{a.preset}` scenes rendered at {', '.join(f'{f:g}' for f in a.fovs)} "
        "deg)", "Command: `.venv/bin/python benchmarks/bench_focal.py`",
        "| true FOV [deg] | run | FOV used [deg] | ATE [% path] | track depth AbsRel | world 3D acc all / dyn |")
    for key, r in results.items():
        fov, name = key.split("|")
        m = r["metrics"]
        lines.append(f"| {fov} | {name} | {r['fov_used_deg']:.1f} | {fmt(m['camera']['ate_pct_path'], 2)} | "
                     f"{fmt(m['track_depth']['abs_rel_depth'], 4)} | {fmt(m['world_3d']['all']['acc_avg'], 1)} / "
                     f"{fmt(m['world_3d']['dynamic']['acc_avg'], 1)} |")
    write_results(f"focal_{a.preset}", lines, results)
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
