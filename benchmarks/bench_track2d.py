"""Benchmark of dense 2D tracking (issue 3), run on demand: ``.venv/bin/python benchmarks/bench_track2d.py``.

On the same synthetic scenes in one run: grid + convex upsampler (default) vs grid + bilinear upsampling vs
direct tracking of every pixel, with and without tracking every frame ("w/o T.E.F"), and the authors'
rounding rule for covering; the default configuration and the sparse tracker also on more seeds of the
``default`` preset (``--seeds``). Reports 2D delta_avg / occlusion accuracy of the ground-truth queries, coverage,
time and peak memory (RSS), and writes ``benchmarks/results/track2d.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from trackingworld.config import Track2DConfig
from trackingworld.eval.dense import coverage
from trackingworld.eval.match import match_queries
from trackingworld.eval.tracks import tapvid_2d
from trackingworld.io.frames import read_frames
from trackingworld.pipeline.tracks import track_video
from trackingworld.synth import render_and_write
from trackingworld.tracking2d import FlowTracker

CONFIGS = {
    "grid+convex (default)": {},
    "grid+convex mean (paper)": {"upsampler": "convex-mean"},
    "grid+bilinear": {"upsampler": "bilinear"},
    "direct every pixel": {"dense_mode": "direct"},
    "grid+convex, r=0 (rounding)": {"cover_radius": 0.0},
    "grid+convex, w/o T.E.F": {"first_frame_only": True},
    "grid+convex, query stride 10": {"query_stride": 10},
    "grid+convex, re-find patch test 4": {"flow_refind_patch_diff": 4.0},
    "grid+convex, DIS flow without the median": {"flow_median": 0},
}
SPREAD = ("grid+convex (default)", "grid+convex, DIS flow without the median")


def _cell(v) -> str:
    return "-" if v is None else str(v)


def peak_rss_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6


def evaluate(scene: Path, configs: dict) -> list[dict]:
    frames, _ = read_frames(scene / "input" / "frames")
    g = np.load(scene / "gt.npz")
    T, H, W = frames.shape[:3]
    rows = []
    for name, kw in configs.items():
        t0 = time.perf_counter()
        tr = track_video(frames, Track2DConfig(**kw), verbose=False)
        dt = time.perf_counter() - t0
        m = match_queries(tr.tracks, tr.visible, np.zeros(tr.tracks.shape[:2] + (3,), np.float32),
                          np.zeros(len(tr.tracks), bool), g["query_frame"], g["query_uv"])
        a = tapvid_2d(m.uv, m.visible, g["tracks_uv"], g["tracks_vis"], g["query_frame"], (W, H))
        c = coverage(tr.tracks, tr.visible, H, W)
        rows.append({"scene": scene.name, "config": name, "seconds": round(dt, 2), "tracks": len(tr.tracks),
                     "delta_avg": round(a["delta_avg"], 1), "occlusion_acc": round(a["occlusion_acc"], 1),
                     "coverage": round(c["coverage"], 3), "coverage_r1": round(c["coverage_r1"], 3)})
        print(rows[-1], file=sys.stderr, flush=True)
    # the weight-free tracker itself, from each ground-truth query (no dense output, no matching)
    q = np.concatenate([g["query_frame"][:, None], g["query_uv"]], 1).astype(np.float32)
    t0 = time.perf_counter()
    r = FlowTracker().track(frames, q)
    a = tapvid_2d(r.tracks, r.visible, g["tracks_uv"], g["tracks_vis"], g["query_frame"], (W, H))
    rows.append({"scene": scene.name, "config": "flow tracker at the queries (sparse)",
                 "seconds": round(time.perf_counter() - t0, 2), "tracks": len(q), "delta_avg": round(a["delta_avg"], 1),
                 "occlusion_acc": round(a["occlusion_acc"], 1), "coverage": None, "coverage_r1": None})
    print(rows[-1], file=sys.stderr, flush=True)
    return rows


def seed_spread(tmp: Path, preset: str, seeds: list[int]) -> list[dict]:
    """The default configuration, its DIS flow without the median and the sparse tracker on more random scenes of
    one preset: one scene's figure moves by several points with the scene (83.4 to 88.1 over seeds 0-3), so
    decisions should not rest on seed 0 alone."""
    rows = []
    for seed in seeds:
        scene = render_and_write(tmp / f"{preset}_{seed}", preset, seed, verbose=False)
        for r in evaluate(scene, {k: CONFIGS[k] for k in SPREAD}):
            rows.append(r | {"scene": f"{preset} seed {seed}"})
    return rows


def speed(tmp: Path, frames: int, size: tuple[int, int]) -> dict:
    scene = render_and_write(tmp / "speed", "default", 1, frames=frames, size=size, verbose=False)
    video, _ = read_frames(scene / "input" / "frames")
    rss0 = peak_rss_gb()
    t0 = time.perf_counter()
    tr = track_video(video, Track2DConfig(), verbose=False)
    return {"frames": frames, "size": f"{size[0]}x{size[1]}", "seconds": round(time.perf_counter() - t0, 1),
            "tracks": len(tr.tracks), "peak_rss_gb": round(peak_rss_gb(), 2), "rss_before_gb": round(rss0, 2)}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "track2d"))
    ap.add_argument("--no-speed", action="store_true")
    ap.add_argument("--seeds", default="1,2,3",
                    help="more seeds of the default preset (the default config and DIS without the median only)")
    a = ap.parse_args()
    rows, sp = [], None
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for preset in ("default", "hard"):
            scene = render_and_write(tmp / preset, preset, 0, verbose=False)
            rows += evaluate(scene, CONFIGS)
        seeds = [int(x) for x in a.seeds.split(",") if x.strip()]
        spread = seed_spread(tmp, "default", seeds) if seeds else []
        rows += spread
        if not a.no_speed:
            sp = speed(tmp, 30, (854, 480))
            print(sp, file=sys.stderr)
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps({"rows": rows, "speed": sp}, indent=2) + "\n")
    lines = ["| scene | config | delta_avg | occl. acc | coverage | coverage r<=1px | tracks | time [s] |",
             "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['scene']} | {r['config']} | {r['delta_avg']} | {r['occlusion_acc']} | {_cell(r['coverage'])} | "
              f"{_cell(r['coverage_r1'])} | {r['tracks']} | {r['seconds']} |" for r in rows]
    if spread:
        for cfg in (*SPREAD, "flow tracker at the queries (sparse)"):
            vals = [r["delta_avg"] for r in rows if r["config"] == cfg and r["scene"].startswith("default")]
            lines += ["", f"{cfg}: delta_avg over default seeds 0,{a.seeds}: mean {np.mean(vals):.1f}, "
                      f"min {min(vals)}, max {max(vals)}."]
    if sp:
        lines += ["", f"Speed: {sp['frames']} frames at {sp['size']}: {sp['seconds']} s, {sp['tracks']} tracks, "
                  f"peak RSS {sp['peak_rss_gb']} GB (process, including the rendering before it)."]
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
