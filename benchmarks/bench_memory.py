"""Peak memory of ``trackingworld run`` on real videos, against the estimate that warns before a run too large for
the machine (``trackingworld.memory``).

    .venv/bin/python benchmarks/bench_memory.py            # pstudio.mp4 and dog.mp4 of ../shared/data, 40 frames
    .venv/bin/python benchmarks/bench_memory.py --video ../shared/data/pstudio.mp4 --frames 150 --name pstudio150

Each video runs twice in a scratch folder with the weight-free default path: once to fill the cache of the dense
tracks and priors (``OUT/priors``, untimed), then the measured run, which reads them, so the figures are the
lifting's (the 2D tracker's own are ``bench_track2d.py``'s). Each run is a process of its own under a small parent
that reads its peak RSS (``getrusage(RUSAGE_CHILDREN)``: the largest resident set of the one child it waited for).
Writes ``benchmarks/results/memory_NAME.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from _common import OPT_STAGES, md_table_start, scratch_dir, write_results  # noqa: I001 (a sibling script module)
from trackingworld.memory import estimate_peak_bytes, guess_tracks

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
# a parent process per run: its only child's peak resident set, in kB (Linux's ru_maxrss unit)
PEAK_OF_CHILD = ("import resource, subprocess, sys; rc = subprocess.call(sys.argv[1:]); "
                 "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss); sys.exit(rc)")


def measured_run(video: Path, frames: int, out: Path) -> dict:
    """``trackingworld run VIDEO --max-frames FRAMES --out OUT`` in a process of its own: its peak RSS (kB), wall
    time (s) and what it wrote (timings, track count, processing size)."""
    cmd = [sys.executable, "-c", PEAK_OF_CHILD, sys.executable, "-m", "trackingworld.cli.main", "run", str(video),
           "--max-frames", str(frames), "--out", str(out), "--quiet"]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"bench_memory: {video}: the run failed: {done.stderr.strip().splitlines()[-1:]}")
    timings = json.loads((out / "timings.json").read_text())
    report = json.loads((out / "optim.json").read_text())
    return {"peak_kb": int(done.stdout.split()[-1]), "wall_s": wall, "timings": timings,
            "tracks": int(report["tracks"]), "dynamic": int(report.get("dynamic", 0))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--video", type=Path, action="append", help="a video (repeatable; default: pstudio.mp4 and "
                    "dog.mp4 of ../shared/data)")
    ap.add_argument("--frames", type=int, default=40, help="--max-frames of each run (default 40)")
    ap.add_argument("--name", default="real40", help="results file stem: memory_NAME (default real40)")
    ap.add_argument("--keep", action="store_true", help="keep the scratch folder (its path is printed)")
    a = ap.parse_args(argv)
    videos = a.video or [DATA / "pstudio.mp4", DATA / "dog.mp4"]
    work = scratch_dir("bench_memory_", a.keep)
    rows = []
    for video in videos:
        if not video.exists():
            raise SystemExit(f"bench_memory: {video}: no such video")
        out = work / video.stem
        measured_run(video, a.frames, out)  # fills OUT/priors: the tracks, masks and depth
        r = measured_run(video, a.frames, out)
        with np.load(out / "result.npz") as z:  # the frames and processing size the run had
            T, H, W = z["depth"].shape
        rows.append({"video": video.name, "frames": T, "size": [W, H], "tracks": r["tracks"], "dynamic": r["dynamic"],
                     "guessed_tracks": guess_tracks(H, W, T), "peak_kb": r["peak_kb"],
                     "estimate_bytes": estimate_peak_bytes(r["tracks"], T), "wall_s": r["wall_s"],
                     "optimisation_s": sum(r["timings"].get(k, 0.0) for k in OPT_STAGES),
                     "rigid_movers_s": r["timings"].get("rigid_movers", 0.0)})
        print(f"[bench] {video.name}: peak {r['peak_kb']:,} kB, {r['wall_s']:.1f} s", file=sys.stderr)
    command = " ".join([".venv/bin/python benchmarks/bench_memory.py", *(sys.argv[1:] if argv is None else argv)])
    lines = md_table_start(
        f"# Peak memory of `trackingworld run` ({a.frames} frames, weight-free priors, tracks and priors cached)",
        f"`{command}`",
        "| video | frames | size | tracks | dynamic | peak RSS [kB] | estimate [GB] | peak / estimate | guessed tracks "
        "| optimisation [s] | rigid step [s] |")
    for r in rows:
        peak = r["peak_kb"] * 1024
        lines.append(f"| {r['video']} | {r['frames']} | {r['size'][0]}x{r['size'][1]} | {r['tracks']:,} | "
                     f"{r['dynamic']:,} | {r['peak_kb']:,} | {r['estimate_bytes'] / 1e9:.2f} | "
                     f"{peak / r['estimate_bytes']:.2f} | {r['guessed_tracks']:,} | {r['optimisation_s']:.1f} | "
                     f"{r['rigid_movers_s']:.1f} |")
    write_results(f"memory_{a.name}", lines, {"rows": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
