"""How the optimisation's cost grows with the number of frames (issue 4: 120 frames should cost about 4x 30
frames, not 16x), on synthetic scenes with the priors given, so that every length runs the same code path.

    .venv/bin/python benchmarks/bench_scaling.py      # writes benchmarks/results/scaling_default.md
    python benchmarks/bench_scaling.py --device cuda  # optimisation on the GPU: scaling_default_cuda.md
    .venv/bin/python benchmarks/bench_scaling.py --repeat 3  # each window's fastest of three passes

One scene is rendered at the longest length; every shorter length runs on each of the non-overlapping windows
of that many frames it contains (30 frames of 120: frames 0-29, 30-59, 60-89, 90-119), so that the comparison
is between a video and the clips it is made of: what the scene holds changes along the video (a mover enters
late), and the first clip alone would make a longer video look dearer than its length makes it. Dense 2D
tracks are computed per window and kept out of the figures: this measures the optimiser (labels, stages 1-3,
classify, rebuild, video depth, from ``timings.json``), and counts what it worked on.
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
from trackingworld.synth.scene import PRESETS, SceneConfig


def cut_scene(scene: Path, out: Path, start: int, T: int) -> Path:
    """Frames ``start`` .. ``start + T - 1`` of a rendered scene (inputs and ground truth) as a scene folder of its
    own: the ground-truth query tracks whose query frame lies in the window, frame indices shifted; the long-range
    flow's ground truth only where both of its frames do."""
    import shutil

    from trackingworld.io.atomic import write_npz

    (out / "input" / "frames").mkdir(parents=True, exist_ok=True)
    (out / "input" / "masks").mkdir(parents=True, exist_ok=True)
    for sub in ("frames", "masks"):
        for f in sorted((scene / "input" / sub).iterdir())[start:start + T]:
            shutil.copy(f, out / "input" / sub / f.name)
    np.save(out / "input" / "depth.npy", np.load(scene / "input" / "depth.npy")[start:start + T])
    shutil.copy(scene / "input" / "intrinsics.txt", out / "input" / "intrinsics.txt")
    shutil.copy(scene / "scene.json", out / "scene.json")
    g = dict(np.load(scene / "gt.npz"))
    keep = (g["query_frame"] >= start) & (g["query_frame"] < start + T)
    for k in ("poses_c2w", "depth", "dynamic", "bg_mover", "instance"):
        g[k] = g[k][start:start + T]
    for k in ("tracks_xyz", "tracks_uv", "tracks_vis"):
        g[k] = g[k][keep][:, start:start + T]
    for k in ("query_frame", "query_uv", "tracks_dynamic", "tracks_bg_mover"):
        g[k] = g[k][keep]
    g["query_frame"] = g["query_frame"] - start
    src, dst = (int(v) - start for v in g["flow_frames"])
    inside = 0 <= src < T and 0 <= dst < T
    g["flow_frames"] = np.array([src, dst] if inside else [T, 0])  # a source frame past the end: not evaluated
    write_npz(out / "gt.npz", **g)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--preset", default="default", choices=sorted(PRESETS))
    ap.add_argument("--frames", type=int, nargs="+", default=[30, 60, 120])
    ap.add_argument("--size", type=int, nargs=2, default=[320, 240], metavar=("W", "H"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--device", default="cpu", help="where the optimisation runs (cpu | cuda | cuda:N)")
    ap.add_argument("--keep", action="store_true", help="keep the scratch folder of scenes, tracks and runs")
    ap.add_argument("--name", help="results file stem (default: scaling_<preset>[_<device>])")
    ap.add_argument("--scene", action="append", default=[], metavar="FIELD=VALUE",
                    help="a SceneConfig field of the rendered video (repeatable), e.g. cam_speed=0.025 for a longer "
                         "video inside the room")
    ap.add_argument("--repeat", type=int, default=1,
                    help="passes over every window; each window's fastest is kept (runs on a busy machine vary)")
    a = ap.parse_args(argv)
    scene_over = {}  # each --scene value in its SceneConfig field's own type (frames and counts are int)
    for kv in a.scene:
        k, _, v = kv.partition("=")
        if k not in SceneConfig.__dataclass_fields__:
            ap.error(f"--scene {kv}: {k!r} is not a SceneConfig field")
        try:
            scene_over[k] = type(getattr(SceneConfig(), k))(v)
        except ValueError:
            ap.error(f"--scene {kv}: {v!r} is not of type {type(getattr(SceneConfig(), k)).__name__}")
    work = scratch_dir("bench_scaling_", a.keep)
    full = render_and_write(work / "full", a.preset, a.seed, max(a.frames), tuple(a.size), verbose=False,
                            **scene_over)
    Tmax = max(a.frames)
    windows = [(T, start) for T in sorted(a.frames) for start in range(0, Tmax - T + 1, T)]
    runs: dict[tuple[int, int], dict] = {}  # the fastest pass of each window
    for rep in range(a.repeat):
        for T, start in windows:
            scene = work / f"scene{T}_{start}"
            tracks = work / f"tracks{T}_{start}.npz"
            if rep == 0:
                cut_scene(full, scene, start, T)
                tracks_file(scene, tracks)
            inp = scene / "input"
            cfg = RunConfig(device=a.device,
                            inputs=InputConfig(input=str(inp / "frames"), depth=str(inp / "depth.npy"),
                                               masks=str(inp / "masks"), intrinsics=str(inp / "intrinsics.txt")),
                            track2d=Track2DConfig(tracker="file", tracks_file=str(tracks)),
                            optim=OptimConfig(verbose=False))
            out = work / f"run{T}_{start}"
            r = run_and_evaluate(cfg, out, scene, f"{T} frames from frame {start}, pass {rep + 1}")
            r["optim"] = json.loads((out / "optim.json").read_text())
            r["observations"] = int(np.load(out / "result.npz")["visible"].sum())
            r["start"] = start
            r["optimisation_s"] = sum(r["timings"].get(s, 0.0) for s in OPT_STAGES)
            if (T, start) not in runs or r["optimisation_s"] < runs[T, start]["optimisation_s"]:
                runs[T, start] = r
    results: dict[int, list[dict]] = {}
    for T, start in windows:
        results.setdefault(T, []).append(runs[T, start])

    def mean(rs, f):
        """Mean of ``f`` over the windows where it is defined (a window may hold no ground-truth query track)."""
        v = [f(r) for r in rs]
        v = [x for x in v if x is not None]
        return float(np.mean(v)) if v else float("nan")

    def world(r):
        return r["metrics"]["world_3d"]["all"].get("acc_avg")

    dev_arg = (("" if a.device == "cpu" else f" --device {a.device}")
               + (f" --repeat {a.repeat}" if a.repeat > 1 else "")
               + ("" if a.frames == [30, 60, 120] else " --frames " + " ".join(map(str, a.frames)))
               + "".join(f" --scene {kv}" for kv in a.scene) + (f" --name {a.name}" if a.name else ""))
    T0 = min(results)
    base = mean(results[T0], lambda r: r["optimisation_s"])
    lines = md_table_start(
        f"# Optimisation cost against the number of frames (`{a.preset}` scene"
        f"{''.join(', ' + kv for kv in a.scene)}, {a.size[0]}x{a.size[1]}, priors "
        f"given, seed {a.seed}, optimisation on {a.device})",
        f"Command: `.venv/bin/python benchmarks/bench_scaling.py{dev_arg}`",
        "| frames | windows | tracks | visible observations | optimisation [s] | x of the shortest | "
        "us per observation | " +
        " | ".join(f"{s} [s]" for s in OPT_STAGES) + " | ATE [% path] | world 3D acc |")
    lines[1:1] = ["", f"Means over the non-overlapping windows of each length in one {Tmax}-frame video; "
                  f"'x of the shortest': the mean optimisation time over that of the {T0}-frame windows (linear "
                  f"cost: {Tmax // T0}x at {Tmax} frames); 'us per observation': optimisation time over the visible "
                  f"observations of the result (the data the stages work on), constant when the cost is linear in it." +
                  (f" Each window's fastest of {a.repeat} passes over all of them (the stages' times are that "
                   f"pass's)." if a.repeat > 1 else "")]
    for T, rs in results.items():
        opt = mean(rs, lambda r: r["optimisation_s"])
        per_obs = mean(rs, lambda r: 1e6 * r["optimisation_s"] / max(r["observations"], 1))
        lines.append(f"| {T} | {len(rs)} | {mean(rs, lambda r: r['optim']['tracks']):,.0f} | "
                     f"{mean(rs, lambda r: r['observations']):,.0f} | {opt:.1f} | {opt / base:.1f} | {per_obs:.2f} | " +
                     " | ".join(f"{np.mean([r['timings'].get(s, 0.0) for r in rs]):.1f}" for s in OPT_STAGES) +
                     f" | {mean(rs, lambda r: r['metrics']['camera']['ate_pct_path']):.2f} | "
                     f"{mean(rs, world):.1f} |")
    lines += ["", "Every window:", "", "| frames | first frame | tracks | visible observations | dynamic tracks | "
              "optimisation [s] | " + " | ".join(f"{s} [s]" for s in OPT_STAGES) + " | ATE [% path] | world 3D acc |",
              "|" + "---|" * (8 + len(OPT_STAGES))]
    for T, rs in results.items():
        for r in rs:
            m, tm = r["metrics"], r["timings"]
            lines.append(f"| {T} | {r['start']} | {r['optim']['tracks']:,} | {r['observations']:,} | "
                         f"{r['optim']['dynamic']:,} | {r['optimisation_s']:.1f} | " +
                         " | ".join(f"{tm.get(s, 0.0):.1f}" for s in OPT_STAGES) +
                         f" | {fmt(m['camera']['ate_pct_path'], 2)} | {fmt(world(r), 1)} |")
    stem = a.name or f"scaling_{a.preset}" + ("" if a.device == "cpu" else "_" + a.device.replace(":", "_"))
    write_results(stem, lines, {str(k): v for k, v in results.items()})
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
