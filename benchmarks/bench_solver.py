"""The default structured solver against the paper's Adam schedule, on the same input: loss of each stage, time of
each stage, and the errors against ground truth.

    .venv/bin/python benchmarks/bench_solver.py [--preset default]   # writes benchmarks/results/solver_<preset>.md

Both rows share one set of dense 2D tracks and the scene's given priors. The losses are the same objectives
evaluated on each solver's answer (``DIR/optim.json``); Adam runs the paper's 1000 / 2000 / 1000 iterations.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from _common import fmt, md_table_start, run_and_evaluate, scratch_dir, tracks_file, write_results  # noqa: I001 (a sibling script module)
from trackingworld.config import InputConfig, OptimConfig, RunConfig, Track2DConfig
from trackingworld.io.frames import read_frames
from trackingworld.synth import render_and_write
from trackingworld.synth.scene import PRESETS

SOLVERS = {"lm (default)": "lm", "adam (paper schedule)": "adam"}
STAGES = ("stage1", "stage2", "stage3")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--preset", default="default", choices=sorted(PRESETS))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep", action="store_true", help="keep the scratch folder of scenes, tracks and runs")
    a = ap.parse_args(argv)
    work = scratch_dir("bench_solver_", a.keep)
    scene = render_and_write(work / "scene", a.preset, a.seed, verbose=False)
    inp = scene / "input"
    frames, _ = read_frames(str(inp / "frames"))
    tracks = tracks_file(scene, work / "tracks.npz")
    results = {}
    for name, solver in SOLVERS.items():
        cfg = RunConfig(inputs=InputConfig(input=str(inp / "frames"), depth=str(inp / "depth.npy"),
                                           masks=str(inp / "masks"), intrinsics=str(inp / "intrinsics.txt")),
                        track2d=Track2DConfig(tracker="file", tracks_file=str(tracks)),
                        optim=OptimConfig(verbose=False, solver=solver))
        out = work / solver
        r = run_and_evaluate(cfg, out, scene, name)
        r["optim"] = json.loads((out / "optim.json").read_text())
        results[name] = r
    lm, adam = (results[k] for k in SOLVERS)
    head = ("| solver | stage 1 loss / s | stage 2 loss / s | stage 3 loss / s | stages 1-3 [s] | ATE [% path] | "
            "track depth AbsRel | world 3D acc all / dyn |")
    lines = md_table_start(f"# Solvers on the `{a.preset}` scene ({frames.shape[0]} frames, {frames.shape[2]}x"
                           f"{frames.shape[1]})", f"Command: `.venv/bin/python benchmarks/bench_solver.py --preset "
                           f"{a.preset}`", head)
    for name, r in results.items():
        o, t, m = r["optim"], r["timings"], r["metrics"]
        cells = [f"{o.get(s, {}).get('loss', float('nan')):.6g} / {t.get(s, 0.0):.1f}" for s in STAGES]
        lines.append(f"| {name} | {' | '.join(cells)} | {sum(t.get(s, 0.0) for s in STAGES):.1f} | "
                     f"{fmt(m['camera']['ate_pct_path'], 2)} | {fmt(m['track_depth']['abs_rel_depth'], 4)} | "
                     f"{fmt(m['world_3d']['all']['acc_avg'], 1)} / {fmt(m['world_3d']['dynamic']['acc_avg'], 1)} |")
    speed = {s: adam["timings"].get(s, 0.0) / max(lm["timings"].get(s, 0.0), 1e-9) for s in STAGES}
    total = sum(adam["timings"].get(s, 0.0) for s in STAGES) / max(sum(lm["timings"].get(s, 0.0) for s in STAGES),
                                                                   1e-9)
    lines += ["", "Adam time / lm time: " + ", ".join(f"{s} {v:.1f}x" for s, v in speed.items())
              + f", stages 1-3 {total:.1f}x.",
              "Stage losses: lower is better; each is the stage's own objective evaluated on the solver's answer."]
    write_results(f"solver_{a.preset}", lines, results)
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
