"""``trackingworld run``: load inputs, run a method, write the result folder atomically."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from trackingworld.config import RunConfig
from trackingworld.errors import InputError
from trackingworld.io.atomic import write_json
from trackingworld.io.result import CONFIG_FILE, Result, save_result
from trackingworld.pipeline.baseline import run_baseline
from trackingworld.pipeline.inputs import load_inputs
from trackingworld.pipeline.world import run_trackingworld

METHODS = {"trackingworld": run_trackingworld, "baseline": run_baseline}
DEFAULT_METHOD = "trackingworld"


def run(cfg: RunConfig, out_dir: str | Path, verbose: bool = True) -> Result:
    out_dir = Path(out_dir)
    if cfg.method not in METHODS:
        raise InputError(f"unknown method {cfg.method!r} (available: {', '.join(METHODS)})")
    if cfg.device.startswith("cuda"):
        import torch

        if not torch.cuda.is_available():
            raise InputError("--device cuda: this torch build has no CUDA device (install a CUDA build of torch)")
    if cfg.track2d.tracker == "file" and cfg.inputs.resize:
        raise InputError(f"{cfg.track2d.tracks_file}: precomputed tracks are at the input resolution; drop --resize")
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    inp = load_inputs(cfg.inputs, verbose)
    timings["load_inputs"] = time.perf_counter() - t0
    result = METHODS[cfg.method](inp, cfg, timings)
    timings["total"] = time.perf_counter() - t0
    save_result(out_dir, result)
    write_json(out_dir / CONFIG_FILE, cfg.to_dict())
    write_json(out_dir / "timings.json", timings)
    if verbose:
        print(f"[run] {result.num_tracks} tracks x {result.num_frames} frames written to {out_dir} "
              f"in {timings['total']:.1f} s", file=sys.stderr)
    return result
