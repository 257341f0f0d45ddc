"""Shared by the benchmark scripts: dense tracks computed once per scene, and one evaluated run."""

from __future__ import annotations

import argparse
import atexit
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from trackingworld.config import RunConfig, Track2DConfig
from trackingworld.eval.evaluate import evaluate_to_file, load_gt
from trackingworld.eval.match import match_queries
from trackingworld.eval.tracks import eval_points
from trackingworld.eval.trajectory import apply_sim3, sim3_from_poses
from trackingworld.geometry import nearest_pixel
from trackingworld.io.atomic import write_npz
from trackingworld.io.frames import read_frames
from trackingworld.io.result import Result, load_result
from trackingworld.memory import reuse_freed_memory
from trackingworld.pipeline.run import run
from trackingworld.pipeline.tracks import track_video
from trackingworld.reproducible import environment

reuse_freed_memory()  # the benchmarks run the pipeline in-process with the CLI's allocator setting

# the optimisation's stages in timings.json (what "optimisation [s]" adds up)
OPT_STAGES = ("labels", "stage1", "stage2", "prior_field", "classify", "rebuild_static", "depth_movers",
              "static_outliers", "static_refit", "stage3", "video_depth", "photo_static",
              "occluded_static", "photo_moving", "rigid_movers")


def scratch_dir(prefix: str, keep: bool = False) -> Path:
    """A fresh folder for a bench's scenes, tracks and runs, removed when the script exits unless ``keep``
    (``--keep``: its path is printed, to look at the runs or profile them)."""
    path = Path(tempfile.mkdtemp(prefix=prefix))
    if keep:
        print(f"[bench] scratch folder kept: {path}", file=sys.stderr)
    else:
        atexit.register(shutil.rmtree, path, True)
    return path


def tracks_file(scene: Path, path: Path, **track2d) -> Path:
    """Dense tracks of a rendered scene's frames written in the CoTracker layout, for ``--tracks`` (every row
    shares them); ``track2d``: Track2DConfig fields other than the defaults."""
    frames, _ = read_frames(str(scene / "input" / "frames"))
    return write_tracks(track_video(frames, Track2DConfig(**track2d), verbose=False), path)


def write_tracks(tr, path: Path) -> Path:
    """A TrackResult written as a tracks file in the CoTracker layout (``--tracks``, ``tracker="file"``)."""
    write_npz(path, tracks=tr.tracks.transpose(1, 0, 2), visibility=tr.visible.T, queries=tr.queries)
    return path


def run_and_evaluate(cfg: RunConfig, out: Path, scene: Path, name: str) -> dict:
    """Run ``cfg`` into ``out``, evaluate against ``scene``: metrics, timings and wall time (s)."""
    t0 = time.perf_counter()
    run(cfg, out, verbose=False)
    wall = time.perf_counter() - t0
    m = evaluate_to_file(out, scene)
    print(f"[bench] {name}: {wall:.1f} s", file=sys.stderr)
    return {"metrics": m, "timings": json.loads((out / "timings.json").read_text()), "wall_s": wall}


def fmt(v, nd: int) -> str:
    """A table cell: ``v`` with ``nd`` decimals, ``-`` for a missing value."""
    return "-" if v is None else f"{v:.{nd}f}"


def md_table_start(title: str, command: str, head: str) -> list[str]:
    """Title, command line, header and separator of a markdown results table."""
    return [title, "", command, "", head, "|" + "---|" * (head.count("|") - 1)]


def write_results(stem: str, lines: list[str], data) -> None:
    """``benchmarks/results/STEM.md`` (and printed) from ``lines``, ``STEM.json`` from ``data``; both end with the
    library versions that made them (``reproducible.environment``; in the JSON under ``"environment"`` when
    ``data`` is a dict)."""
    env = environment()
    lines = [*lines, "", "Environment: " + ", ".join(f"{k} {v}" for k, v in env["packages"].items())
             + f", Python {env['python']}, {env['cpus']} CPUs ({env['cpu']['model']}; OpenCV's "
               f"{env['ipp'].split(' (')[0]})."]
    if isinstance(data, dict):
        data = {**data, "environment": env}
    out = Path(__file__).parent / "results"
    out.mkdir(exist_ok=True)
    (out / f"{stem}.md").write_text("\n".join(lines) + "\n")
    (out / f"{stem}.json").write_text(json.dumps(data, indent=1, default=float))
    print("\n".join(lines))


def probe_inputs(doc: str, argv=None) -> tuple[Path, Path, Result, dict]:
    """A probe's command line ``RUN SCENE`` (a ``trackingworld run`` folder, the synthetic scene it ran on) ->
    (run folder, scene folder, the result, the scene's ground truth cut to the result's frames)."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", type=Path)
    ap.add_argument("scene", type=Path)
    a = ap.parse_args(argv)
    res = load_result(a.run)
    return a.run, a.scene, res, load_gt(a.scene, res.depth.shape[0])


def scored_queries(res: Result, gt: dict, xyz: np.ndarray | None = None):
    """The ground-truth queries read from a result as the world 3D accuracy reads them (``eval.evaluate``): (the
    matched queries (``eval.match``), their world positions ``[Nq,T,3]`` after the Sim(3) of the camera poses, their
    errors ``[Nq,T]`` metres, the observations the metric scores ``[Nq,T]`` bool: seen in the truth, not at the query
    frame). ``xyz [N,T,3]`` stands in for the result's world positions (None: its own)."""
    qf = gt["query_frame"]
    m = match_queries(res.tracks_2d, res.visible, res.tracks_3d if xyz is None else xyz, res.is_dynamic, qf,
                      gt["query_uv"])
    aligned = apply_sim3(sim3_from_poses(res.poses_c2w, gt["poses_c2w"]), m.xyz)
    scored = eval_points(qf, gt["tracks_vis"].shape[1]) & gt["tracks_vis"]
    return m, aligned, np.linalg.norm(aligned - gt["tracks_xyz"], axis=-1), scored


def query_pixels(res: Result):
    """(x [N], y [N]) int: each result track's pixel at its query frame, to read ground-truth maps there."""
    _, H, W = res.depth.shape
    return nearest_pixel(res.tracks_2d[np.arange(res.num_tracks), res.query_frame], W, H)


def query_objects(gt: dict) -> np.ndarray:
    """[Nq] int: the ground-truth instance under each ground-truth query's pixel at its query frame (the object it
    starts on; 0 the static room)."""
    H, W = gt["instance"].shape[1:]
    x, y = nearest_pixel(gt["query_uv"], W, H)
    return gt["instance"][gt["query_frame"], y, x]
