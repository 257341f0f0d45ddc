"""Running the configured 2D tracker over a video: dense tracks of almost all pixels of all frames."""

from __future__ import annotations

import time

import numpy as np

from trackingworld.config import UPSAMPLERS, Track2DConfig
from trackingworld.errors import InputError
from trackingworld.tracking2d.base import TrackResult
from trackingworld.tracking2d.dense import DenseConfig, DenseTracker
from trackingworld.tracking2d.flow_tracker import FlowTracker, FlowTrackerConfig
from trackingworld.tracking2d.upsample import UpsampleConfig


def check_track2d(cfg: Track2DConfig) -> None:
    """InputError (one line, naming the field) for a flow tracker setting out of its range, before any work."""
    for name in ("flow_drag_px", "flow_refind_patch_diff"):
        v = getattr(cfg, name)
        if not (np.isfinite(v) and v >= 0):
            raise InputError(f"{name} {v}: 0 (off) or a positive number")
    for name in ("flow_median", "flow_skip_stride"):
        if getattr(cfg, name) < 0:
            raise InputError(f"{name} {getattr(cfg, name)}: 0 (off) or a positive number")


def make_tracker(cfg: Track2DConfig, verbose: bool = True, device: str = "cpu"):
    if cfg.tracker == "flow":
        return FlowTracker(FlowTrackerConfig(preset=cfg.flow_preset, patch_size=cfg.flow_patch[0],
                                             patch_stride=cfg.flow_patch[1], skip_stride=cfg.flow_skip_stride,
                                             drag_abs_px=cfg.flow_drag_px, median_radius=cfg.flow_median,
                                             refind_patch_diff=cfg.flow_refind_patch_diff,
                                             verbose=verbose))
    if cfg.tracker == "cotracker3":
        from trackingworld.tracking2d.cotracker import CoTrackerConfig, CoTrackerTracker

        return CoTrackerTracker.from_spec(CoTrackerConfig(spec=cfg.cotracker, device=device, verbose=verbose))
    raise InputError(f"unknown tracker {cfg.tracker!r} (available: flow, cotracker3, file)")


def upsample_config(name: str) -> UpsampleConfig:
    """The upsampler named on the command line: convex | convex-mean | bilinear."""
    if name == "convex-mean":
        return UpsampleConfig(mode="convex", affine_ridge=-1.0)
    if name not in UPSAMPLERS:
        raise InputError(f"unknown upsampler {name!r} (choose from {', '.join(UPSAMPLERS)})")
    return UpsampleConfig(mode=name)


def track_video(frames: np.ndarray, cfg: Track2DConfig, timings: dict | None = None, device: str = "cpu",
                verbose: bool = True) -> TrackResult:
    """Dense tracks ``[N,T,2]`` of the video ``frames [T,H,W,3]`` at the processing resolution."""
    t0 = time.perf_counter()
    if cfg.tracker == "file":
        from trackingworld.io.tracks import load_tracks

        res = load_tracks(cfg.tracks_file, frames.shape[0], (frames.shape[2], frames.shape[1]))
    else:
        dense = DenseTracker(make_tracker(cfg, verbose, device), DenseConfig(
            stride=cfg.grid_stride, query_stride=cfg.query_stride, first_frame_only=cfg.first_frame_only,
            cover_radius=cfg.cover_radius, min_component=cfg.min_component, mode=cfg.dense_mode,
            upsample=upsample_config(cfg.upsampler), device=device, verbose=verbose))
        res = dense.track_all(frames)
    if timings is not None:
        timings["track2d"] = time.perf_counter() - t0
    return res
