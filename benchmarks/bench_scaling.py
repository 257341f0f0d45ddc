"""How the optimisation's cost grows with the number of frames (issue 4: 120 frames should cost about 4x 30
frames, not 16x), on synthetic scenes with the priors given, so that every length runs the same code path.

    .venv/bin/python benchmarks/bench_scaling.py      # writes benchmarks/results/scaling_default.md

One scene is rendered at the longest length; the shorter runs use its first frames (same scene, same camera
path). Dense 2D tracks are computed per length and kept out of the figures: this measures the optimiser (labels,
stages 1-3, classify, rebuild, video depth, from ``timings.json``), and counts what it worked on.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from _common import OPT_STAGES, fmt, md_table_start, run_and_evaluate, scratch_dir, tracks_file, write_results  # noqa: I001 (a sibling script module)
from trackingworld.config import InputConfig, OptimConfig, RunConfig, Track2DConfig
from trackingworld.synth import render_and_write


def cut_scene(scene: Path, out: Path, T: int) -> Path:
    """The first T frames of a rendered scene (inputs and ground truth) as a scene folder of its own."""
    import shutil

    from trackingworld.io.atomic import write_npz

    (out / "input" / "frames").mkdir(parents=True, exist_ok=True)
    (out / "input" / "masks").mkdir(parents=True, exist_ok=True)
    for sub in ("frames", "masks"):
        for f in sorted((scene / "input" / sub).iterdir())[:T]:
            shutil.copy(f, out / "input" / sub / f.name)
    np.save(out / "input" / "depth.npy", np.load(scene / "input" / "depth.npy")[:T])
    shutil.copy(scene / "input" / "intrinsics.txt", out / "input" / "intrinsics.txt")
    shutil.copy(scene / "scene.json", out / "scene.json")
    g = dict(np.load(scene / "gt.npz"))
    keep = g["query_frame"] < T
    for k in ("poses_c2w", "depth", "dynamic", "bg_mover", "instance"):
        g[k] = g[k][:T]
    for k in ("tracks_xyz", "tracks_uv", "tracks_vis"):
        g[k] = g[k][keep][:, :T]
    for k in ("query_frame", "query_uv", "tracks_dynamic", "tracks_bg_mover"):
        g[k] = g[k][keep]
    write_npz(out / "gt.npz", **g)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--preset", default="default")
    ap.add_argument("--frames", type=int, nargs="+", default=[30, 60, 120])
    ap.add_argument("--size", type=int, nargs=2, default=[320, 240], metavar=("W", "H"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep", action="store_true", help="keep the scratch folder of scenes, tracks and runs")
    a = ap.parse_args(argv)
    work = scratch_dir("bench_scaling_", a.keep)
    full = render_and_write(work / "full", a.preset, a.seed, max(a.frames), tuple(a.size), verbose=False)
    results = {}
    for T in sorted(a.frames):
        scene = cut_scene(full, work / f"scene{T}", T)
        inp = scene / "input"
        tracks = tracks_file(scene, work / f"tracks{T}.npz")
        cfg = RunConfig(inputs=InputConfig(input=str(inp / "frames"), depth=str(inp / "depth.npy"),
                                           masks=str(inp / "masks"), intrinsics=str(inp / "intrinsics.txt")),
                        track2d=Track2DConfig(tracker="file", tracks_file=str(tracks)),
                        optim=OptimConfig(verbose=False))
        out = work / f"run{T}"
        r = run_and_evaluate(cfg, out, scene, f"{T} frames")
        r["optim"] = json.loads((out / "optim.json").read_text())
        z = np.load(out / "result.npz")
        r["observations"] = int(z["visible"].sum())
        results[T] = r
    T0 = min(results)
    opt = {T: sum(r["timings"].get(s, 0.0) for s in OPT_STAGES) for T, r in results.items()}
    lines = md_table_start(
        f"# Optimisation cost against the number of frames (`{a.preset}` scene, {a.size[0]}x{a.size[1]}, priors "
        "given)", "Command: `.venv/bin/python benchmarks/bench_scaling.py`",
        "| frames | tracks | visible observations | optimisation [s] | x of the first | " +
        " | ".join(f"{s} [s]" for s in OPT_STAGES) + " | ATE [% path] | world 3D acc |")
    for T, r in results.items():
        m, tm = r["metrics"], r["timings"]
        lines.append(f"| {T} | {r['optim']['tracks']:,} | {r['observations']:,} | {opt[T]:.1f} | "
                     f"{opt[T] / opt[T0]:.1f} | " + " | ".join(f"{tm.get(s, 0.0):.1f}" for s in OPT_STAGES) +
                     f" | {fmt(m['camera']['ate_pct_path'], 2)} | {fmt(m['world_3d']['all']['acc_avg'], 1)} |")
    write_results(f"scaling_{a.preset}", lines, {str(k): v for k, v in results.items()})
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
