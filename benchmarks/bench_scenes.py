"""The ten-scene sweep: the full method (and any variants of it) on `default` seeds 0-7 and `hard` seeds 0-1.

Every figure the README gives "on the ten scenes" comes from this script. Each scene is rendered and densely
tracked once into a cache folder (``--cache``, default ``bench_out/scenes``) and reused by later runs, so the
rows of one run, and of runs on other days, read the same tracks: a change to the optimiser shows by itself.
Rows are named sets of ``trackingworld run`` optimiser flags, the default first, and with ``--baseline`` the
camera-centric lifting last::

    .venv/bin/python benchmarks/bench_scenes.py                       # the default on the ten scenes
    .venv/bin/python benchmarks/bench_scenes.py --row "no slip test=--slip-run 0" --scenes hard:0-1 default:0

Per scene and row: world 3D accuracy all / static / dynamic, static kept static, dynamic recall, bg-mover
recall, camera ATE, track depth and video depth AbsRel each beside the raw prior's on the same pixels,
optimisation time; then each row's means. Written to ``benchmarks/results/scenes.md`` / ``.json`` (``--name``
changes the stem). ``--track FLAGS`` tracks the scenes with other ``trackingworld track2d`` flags (give it a
``--cache`` folder of its own); ``--scenes default:8-11 hard:2`` are scenes no setting was chosen on.
"""

from __future__ import annotations

import argparse
import ast
import hashlib
import json
import shlex
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np

from _common import OPT_STAGES, fmt, md_table_start, run_and_evaluate, tracks_file, write_results  # noqa: I001 (a sibling script module)
from trackingworld import __version__, synth, tracking2d
from trackingworld.cli.main import _optim_args, _optim_config, _track_args, _track_config
from trackingworld.config import InputConfig, RunConfig, Track2DConfig
from trackingworld.synth import render_and_write
from trackingworld.synth.scene import PRESETS

TEN_SCENES = ("default:0-7", "hard:0-1")
# (label, path in the metrics, decimals) of each column
COLUMNS = (
    ("world all", ("world_3d", "all", "acc_avg"), 1),
    ("world static", ("world_3d", "static", "acc_avg"), 1),
    ("world dynamic", ("world_3d", "dynamic", "acc_avg"), 1),
    ("static kept [%]", ("labels", "static_kept_static"), 1),
    ("dynamic recall [%]", ("labels", "dynamic_recall"), 1),
    ("bg-mover recall [%]", ("labels", "bg_mover_recall"), 1),
    ("ATE [% path]", ("camera", "ate_pct_path"), 2),
    ("track depth AbsRel", ("track_depth", "abs_rel_depth"), 4),
    ("prior there", ("track_depth_prior", "abs_rel_depth"), 4),
    ("video depth AbsRel", ("video_depth", "abs_rel_depth"), 4),
    ("prior", ("video_depth_prior", "abs_rel_depth"), 4),
)


def parse_scenes(specs: list[str]) -> list[tuple[str, int]]:
    """``["default:0-7", "hard:1"]`` -> [(preset, seed), ...] in the order given."""
    out = []
    for spec in specs:
        preset, _, seeds = spec.partition(":")
        if not seeds:
            raise SystemExit(f"bench_scenes: scene {spec!r} must be PRESET:SEED or PRESET:FIRST-LAST")
        if preset not in PRESETS:
            raise SystemExit(f"bench_scenes: scene {spec!r}: unknown preset {preset!r}; "
                             f"choose from {', '.join(PRESETS)}")
        a, _, b = seeds.partition("-")
        out += [(preset, s) for s in range(int(a), int(b or a) + 1)]
    return out


def parse_row(text: str):
    """``"NAME=--flag value ..."`` -> (name, OptimConfig) through the CLI's own optimiser flags."""
    name, sep, flags = text.partition("=")
    if not sep or not name.strip():
        raise SystemExit(f"bench_scenes: row {text!r} must be NAME=FLAGS")
    p = argparse.ArgumentParser(prog=f"row {name!r}")
    _optim_args(p)
    p.add_argument("--quiet", action="store_true", default=True)
    return name.strip(), _optim_config(p.parse_args(shlex.split(flags)))


def parse_track(flags: str) -> Track2DConfig:
    """``trackingworld track2d``'s tracking flags -> the Track2DConfig the scenes are tracked with."""
    p = argparse.ArgumentParser(prog="--track")
    _track_args(p)
    return _track_config(p.parse_args(shlex.split(flags)))


def tracker_code(tracker: str = "flow") -> str:
    """A digest of the source files of the 2D tracker ``tracker`` (``Track2DConfig.tracker``): cached tracks made
    by other code are made again. ``cotracker.py`` counts only for the CoTracker tracker, so a change to the model
    loading does not re-track the weight-free scenes."""
    return source_digest(Path(tracking2d.__file__).parent, () if tracker == "cotracker3" else ("cotracker.py",))


def source_digest(package_dir: Path, skip: tuple[str, ...] = ()) -> str:
    """A digest of the ``*.py`` files of a package folder, those named in ``skip`` left out, and of the package's
    top-level ``trackingworld`` modules they import (``geometry``, ``image``, ...): the 2D tracker's patch sampling
    lives in ``trackingworld.image``, so a change there makes other tracks just as a change in the tracker does."""
    files = sorted(f for f in package_dir.glob("*.py") if f.name not in skip)
    root = package_dir.parent
    shared = set()
    for f in files:
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("trackingworld."):
                top = root / (node.module.split(".")[1] + ".py")
                if top.is_file():
                    shared.add(top)
    h = hashlib.sha256()
    for f in files + sorted(shared):
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def cached_scene(cache: Path, preset: str, seed: int, track2d: Track2DConfig,
                 frames: int | None = None) -> tuple[Path, Path]:
    """The scene folder and its dense tracks by ``track2d``, made when missing or made by another package
    version, other generator code (rendered again), other tracking settings or other tracker code. ``frames``:
    rendered at that length (None: the preset's; a cache of the presets' lengths has no length in its stamps)."""
    scene = cache / f"{preset}{seed}"
    tracks = scene / "tracks.npz"
    stamp = scene / "stamp.json"
    want = json.loads(json.dumps({"version": __version__, "preset": preset, "seed": seed,
                                  **({} if frames is None else {"frames": frames}),
                                  "synth": source_digest(Path(synth.__file__).parent),
                                  "track2d": {**asdict(track2d), "code": tracker_code(track2d.tracker)}}))
    have = json.loads(stamp.read_text()) if stamp.exists() else {}
    if not (tracks.exists() and have == want):
        if {**have, "track2d": None} != {**want, "track2d": None}:  # the scene itself: rendered again
            render_and_write(scene, preset, seed, frames, verbose=False)
        fields = {k: v for k, v in asdict(track2d).items() if v != getattr(Track2DConfig(), k)}
        tracks_file(scene, tracks, **fields)
        stamp.write_text(json.dumps(want))
    return scene, tracks


def get(m: dict, path: tuple[str, ...]):
    for k in path:
        m = (m or {}).get(k)
    return m


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=list(TEN_SCENES), help="PRESET:SEED or PRESET:FIRST-LAST")
    ap.add_argument("--row", action="append", default=[], metavar="NAME=FLAGS",
                    help="a variant: trackingworld run's optimiser flags (repeatable); the default row comes first")
    ap.add_argument("--baseline", action="store_true",
                    help="a last row: the camera-centric baseline (--method baseline)")
    ap.add_argument("--track", default="", metavar="FLAGS",
                    help="the scenes' 2D tracking flags (trackingworld track2d's), e.g. '--flow-patch 8,3'")
    ap.add_argument("--cache", type=Path, default=Path("bench_out/scenes"),
                    help="scenes and their dense tracks, kept between runs (one folder per tracking setting)")
    ap.add_argument("--name", default="scenes", help="stem of the results files in benchmarks/results/")
    ap.add_argument("--frames", type=int, default=None,
                    help="render the scenes at this many frames instead of their preset's (give it a --cache folder "
                         "of its own), e.g. 120 for the long videos of the rigid step's key frames")
    a = ap.parse_args(argv)
    if a.frames is not None and a.frames < 2:
        ap.error(f"--frames {a.frames}: a video of 2 frames or more")
    rows = [("default", parse_row("default=")[1], "trackingworld")]
    rows += [(*parse_row(r), "trackingworld") for r in a.row]
    if a.baseline:
        rows.append(("baseline", rows[0][1], "baseline"))
    scenes = parse_scenes(a.scenes)
    track2d = parse_track(a.track)
    a.cache.mkdir(parents=True, exist_ok=True)
    results: dict = {name: {} for name, _, _ in rows}
    for preset, seed in scenes:
        scene, tracks = cached_scene(a.cache, preset, seed, track2d, a.frames)
        inp = scene / "input"
        for i, (name, optim, method) in enumerate(rows):
            given = InputConfig(input=str(inp / "frames"), depth=str(inp / "depth.npy"), masks=str(inp / "masks"),
                                intrinsics=str(inp / "intrinsics.txt"))
            cfg = RunConfig(method=method, inputs=given, optim=optim,
                            track2d=Track2DConfig(tracker="file", tracks_file=str(tracks)))
            r = run_and_evaluate(cfg, a.cache / f"run_{preset}{seed}_{i}", scene, f"{preset} {seed} {name}")
            results[name][f"{preset} {seed}"] = {
                "metrics": r["metrics"], "optim_s": sum(r["timings"].get(k, 0.0) for k in OPT_STAGES)}
    write(results, a)
    return 0


def write(results: dict, a) -> None:
    head = "| row | scene | " + " | ".join(c[0] for c in COLUMNS) + " | optimisation [s] |"
    flags = " ".join([f"--row {shlex.quote(r)}" for r in a.row] + ["--baseline"] * a.baseline +
                     ([f"--track {shlex.quote(a.track)}"] if a.track else []) +
                     ([f"--frames {a.frames}"] if a.frames is not None else []) +
                     ([f"--cache {a.cache}"] if a.cache != Path("bench_out/scenes") else []) +
                     ([f"--name {a.name}"] if a.name != "scenes" else []))
    lines = md_table_start("# The full method on synthetic scenes (same cached dense tracks for every row)",
                           f"Command: `.venv/bin/python benchmarks/bench_scenes.py --scenes {' '.join(a.scenes)}"
                           f"{' ' + flags if flags else ''}`", head)
    def cells(v) -> str:
        return " | ".join(fmt(x, c[2]) for x, c in zip(v, COLUMNS, strict=True))

    for name, per in results.items():
        vals = []
        for scene, r in per.items():
            v = [get(r["metrics"], c[1]) for c in COLUMNS]
            vals.append([np.nan if x is None else float(x) for x in v] + [r["optim_s"]])
            lines.append(f"| {name} | {scene} | {cells(v)} | {r['optim_s']:.1f} |")
        mean = np.nanmean(np.array(vals), 0)
        lines.append(f"| **{name}** | **mean** | {cells(mean[:-1])} | {mean[-1]:.1f} |")
    write_results(a.name, lines, results)


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
