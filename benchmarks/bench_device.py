"""The same video on each device (issue 4: "runs on `--device cuda` too"), run on demand on a machine with a GPU:

    python benchmarks/bench_device.py [--devices cpu cuda] [--frames 30] [--size 854 480]
    # writes benchmarks/results/device_<preset>.md and .json

One synthetic scene (the issue's speed case: 30 frames at 854x480, priors given). Part 1 times the dense 2D
tracker on each device and compares its tracks with the first device's. Part 2 runs the optimisation (labels,
stages 1-3, rebuild, video depth) on each device from the *same* tracks file (the first device's tracks), so the
rows differ only in where the optimiser ran, and evaluates each against the ground truth. The CUDA context is
started before any timing and reported on its own line. CPU figures depend on the machine's core count: the
table says how many threads torch used.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
import torch

from _common import OPT_STAGES, fmt, md_table_start, run_and_evaluate, scratch_dir, write_results, write_tracks  # noqa: I001,E501 (a sibling script module)
from trackingworld.config import InputConfig, OptimConfig, RunConfig, Track2DConfig
from trackingworld.io.frames import read_frames
from trackingworld.pipeline.tracks import track_video
from trackingworld.synth import render_and_write
from trackingworld.synth.scene import PRESETS


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize(device)


def _peak_gpu_gb(device: str) -> float | None:
    return torch.cuda.max_memory_allocated(device) / 1e9 if device.startswith("cuda") else None


def _reset_peak(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.reset_peak_memory_stats(device)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--preset", default="default", choices=sorted(PRESETS))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--size", type=int, nargs=2, default=[854, 480], metavar=("W", "H"))
    ap.add_argument("--devices", nargs="+", default=["cpu", "cuda"])
    ap.add_argument("--keep", action="store_true", help="keep the scratch folder of scenes, tracks and runs")
    a = ap.parse_args(argv)
    gpus = [d for d in a.devices if d.startswith("cuda")]
    if gpus and not torch.cuda.is_available():
        print(f"bench_device: {gpus[0]} asked for but this torch ({torch.__version__}) sees no CUDA device",
              file=sys.stderr)
        return 2
    startup = {}
    for d in gpus:  # the CUDA context and the first kernels, kept out of the rows below
        t0 = time.perf_counter()
        torch.ones(1024, 1024, device=d).matmul(torch.ones(1024, 1024, device=d)).sum().item()
        startup[d] = time.perf_counter() - t0
    work = scratch_dir("bench_device_", a.keep)
    scene = render_and_write(work / "scene", a.preset, a.seed, a.frames, tuple(a.size), verbose=False)
    inp = scene / "input"
    frames, _ = read_frames(str(inp / "frames"))

    track_rows, ref = {}, None
    for d in a.devices:
        _reset_peak(d)
        _sync(d)
        t0 = time.perf_counter()
        tr = track_video(frames, Track2DConfig(), None, d, verbose=False)
        _sync(d)
        secs = time.perf_counter() - t0
        path = write_tracks(tr, work / f"tracks_{d.replace(':', '_')}.npz")
        row = {"seconds": secs, "tracks": int(tr.tracks.shape[0]), "peak_gpu_gb": _peak_gpu_gb(d), "path": str(path)}
        if ref is None:
            ref = tr
        else:  # the first frame's queries come first and in the same order on every device
            n0 = min(int((ref.queries[:, 0] == 0).sum()), int((tr.queries[:, 0] == 0).sum()))
            both = ref.visible[:n0] & tr.visible[:n0]
            row["median_px_to_first"] = float(np.median(np.abs(tr.tracks[:n0] - ref.tracks[:n0])[both]))
            row["visibility_agreement"] = float((ref.visible[:n0] == tr.visible[:n0]).mean())
        track_rows[d] = row
        print(f"[bench] 2D tracks on {d}: {secs:.1f} s, {row['tracks']:,} tracks", file=sys.stderr)

    runs = {}
    for d in a.devices:
        cfg = RunConfig(device=d, inputs=InputConfig(input=str(inp / "frames"), depth=str(inp / "depth.npy"),
                                                     masks=str(inp / "masks"), intrinsics=str(inp / "intrinsics.txt")),
                        track2d=Track2DConfig(tracker="file", tracks_file=track_rows[a.devices[0]]["path"]),
                        optim=OptimConfig(verbose=False))
        _reset_peak(d)
        r = run_and_evaluate(cfg, work / f"run_{d.replace(':', '_')}", scene, f"optimisation on {d}")
        r["optimisation_s"] = sum(r["timings"].get(s, 0.0) for s in OPT_STAGES)
        r["peak_gpu_gb"] = _peak_gpu_gb(d)
        runs[d] = r

    names = {d: (torch.cuda.get_device_name(d) if d.startswith("cuda") else
                 f"CPU, {torch.get_num_threads()} torch threads of {os.cpu_count()} cores") for d in a.devices}
    lines = md_table_start(
        f"# The same scene on each device (`{a.preset}` seed {a.seed}, {a.frames} frames {a.size[0]}x{a.size[1]}, "
        f"priors given; torch {torch.__version__})",
        f"Command: `python benchmarks/bench_device.py --devices {' '.join(a.devices)}`",
        "| device | what it is | 2D tracks [s] | tracks | median px to the first row | visibility agreement | "
        "peak GPU memory [GB] |")
    for d, row in track_rows.items():
        lines.append(f"| {d} | {names[d]} | {row['seconds']:.1f} | {row['tracks']:,} | "
                     f"{fmt(row.get('median_px_to_first'), 3)} | {fmt(row.get('visibility_agreement'), 4)} | "
                     f"{fmt(row['peak_gpu_gb'], 2)} |")
    lines += ["", f"Optimisation from the same tracks file ({a.devices[0]}'s): seconds per stage from `timings.json`.",
              "", "| device | optimisation [s] | " + " | ".join(f"{s} [s]" for s in OPT_STAGES) +
              " | run wall [s] | peak GPU memory [GB] | ATE [% path] | world 3D acc all / dynamic | "
              "track AbsRel (prior) | video AbsRel (prior) |", "|" + "---|" * (8 + len(OPT_STAGES))]
    for d, r in runs.items():
        m, tm = r["metrics"], r["timings"]
        w = m["world_3d"]
        lines.append(
            f"| {d} | {r['optimisation_s']:.1f} | " + " | ".join(f"{tm.get(s, 0.0):.1f}" for s in OPT_STAGES) +
            f" | {r['wall_s']:.1f} | {fmt(r['peak_gpu_gb'], 2)} | {fmt(m['camera']['ate_pct_path'], 3)} | "
            f"{fmt(w['all'].get('acc_avg'), 1)} / {fmt(w['dynamic'].get('acc_avg'), 1)} | "
            f"{m['track_depth']['abs_rel_depth']:.4f} ({m['track_depth_prior']['abs_rel_depth']:.4f}) | "
            f"{m['video_depth']['abs_rel_depth']:.4f} ({m['video_depth_prior']['abs_rel_depth']:.4f}) |")
    for d, s in startup.items():
        lines += ["", f"CUDA start-up on {d} (context and first kernels, not in the rows): {s:.1f} s."]
    write_results(f"device_{a.preset}", lines, {"tracks": track_rows, "runs": runs, "startup_s": startup,
                                                "devices": names})
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
