"""``trackingworld run``: load inputs, dense 2D tracks, priors, a method; write the result folder atomically."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from trackingworld.config import RunConfig
from trackingworld.errors import InputError
from trackingworld.io.atomic import write_json
from trackingworld.io.cache import cached
from trackingworld.io.result import CONFIG_FILE, Result, save_result
from trackingworld.memory import guess_tracks, memory_warning, release_freed_memory
from trackingworld.pipeline.baseline import run_baseline
from trackingworld.pipeline.inputs import Inputs, load_inputs
from trackingworld.pipeline.tracks import check_track2d, track_video
from trackingworld.pipeline.world import check_optim, run_trackingworld
from trackingworld.priors.resolve import resolve_priors, tracks_key
from trackingworld.progress import warn
from trackingworld.reproducible import environment, ipp_off
from trackingworld.tracking2d.base import TrackResult

METHODS = {"trackingworld": run_trackingworld, "baseline": run_baseline}
DEFAULT_METHOD = "trackingworld"
PRIORS_DIR = "priors"  # the cache of tracks and computed priors inside the output folder
TIMINGS_FILE = "timings.json"  # each stage's seconds; written last
ENVIRONMENT_FILE = "environment.json"  # the library versions that made the result (reproducible.environment)


def dense_tracks(inp: Inputs, cfg: RunConfig, cache_dir: Path | None, key: dict, timings: dict,
                 verbose: bool) -> TrackResult:
    """Dense 2D tracks at the processing resolution, reused from ``cache_dir`` when nothing they depend on
    changed (``key``: :func:`~trackingworld.priors.resolve.tracks_key`)."""
    t0 = time.perf_counter()

    def compute():
        tr = track_video(inp.frames, cfg.track2d, None, cfg.device, verbose)
        return {"tracks": tr.tracks, "visible": tr.visible, "confidence": tr.confidence.astype(np.float16),
                "queries": tr.queries}

    path = None if cache_dir is None or cfg.track2d.tracker == "file" else cache_dir / "tracks.npz"
    z = cached(path, key, compute, "2D tracks", verbose)
    timings["track2d"] = time.perf_counter() - t0
    # the confidences as cached (float16): the lifting does not read them, and float32 would hold 2 bytes more of
    # every track at every frame for the whole run
    return TrackResult(z["tracks"], z["visible"], z["confidence"], z["queries"])


def check_run(cfg: RunConfig) -> None:
    """The settings that need no input: InputError on one line before any work (also once for a whole batch)."""
    if cfg.method not in METHODS:
        raise InputError(f"unknown method {cfg.method!r} (available: {', '.join(METHODS)})")
    if cfg.device.startswith("cuda"):
        import torch

        if not torch.cuda.is_available():
            raise InputError("--device cuda: this torch build has no CUDA device (install a CUDA build of torch)")
    if cfg.method == "trackingworld":
        check_optim(cfg.optim)  # before the 2D tracks and the priors, which take minutes
    check_track2d(cfg.track2d)
    if cfg.track2d.tracker == "file" and cfg.inputs.resize:
        raise InputError(f"{cfg.track2d.tracks_file}: precomputed tracks are at the input resolution; drop --resize")


def run(cfg: RunConfig, out_dir: str | Path, verbose: bool = True) -> Result:
    out_dir = Path(out_dir)
    check_run(cfg)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    inp = load_inputs(cfg.inputs, verbose)
    timings["load_inputs"] = time.perf_counter() - t0
    cache_dir = out_dir / PRIORS_DIR if cfg.inputs.cache else None
    T, H, W = inp.frames.shape[:3]
    if cfg.track2d.tracker != "file":  # a guess of the tracks, before the minutes of 2D tracking
        warn(memory_warning(guess_tracks(H, W, T), T, guessed=True), verbose)
    key = tracks_key(cfg, W, H)  # once: it hashes the input (io.cache.content_identity), which both caches key on
    tr = dense_tracks(inp, cfg, cache_dir, key, timings, verbose)
    release_freed_memory()  # the tracker's temporaries (trackingworld.memory)
    warn(memory_warning(tr.tracks.shape[0], T), verbose)
    t1 = time.perf_counter()
    inp, pinfo = resolve_priors(inp, tr, cfg, cache_dir, verbose, key)
    timings["priors"] = time.perf_counter() - t1
    release_freed_memory()  # the priors' models and temporaries
    report: dict = {}
    with ipp_off():  # the lifting's numbers the same from run to run (trackingworld.reproducible)
        result = METHODS[cfg.method](inp, tr, cfg, timings, report)
    timings["total"] = time.perf_counter() - t0
    save_result(out_dir, result)
    write_json(out_dir / CONFIG_FILE, cfg.to_dict())
    write_json(out_dir / "priors.json", pinfo.__dict__)
    write_json(out_dir / ENVIRONMENT_FILE, environment())
    if report:
        write_json(out_dir / "optim.json", report)
    write_json(out_dir / TIMINGS_FILE, timings)  # last: a folder with it holds a finished run (pipeline.batch)
    if verbose:
        print(f"[run] {result.num_tracks} tracks x {result.num_frames} frames written to {out_dir} "
              f"in {timings['total']:.1f} s", file=sys.stderr)
    return result
