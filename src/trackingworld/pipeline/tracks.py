"""Choosing query points and running the configured 2D tracker over a video."""

from __future__ import annotations

import time

import numpy as np

from trackingworld.config import Track2DConfig
from trackingworld.errors import InputError
from trackingworld.tracking2d.base import TrackResult
from trackingworld.tracking2d.flow_tracker import FlowTracker, FlowTrackerConfig, grid_queries


def make_tracker(cfg: Track2DConfig):
    if cfg.tracker == "flow":
        return FlowTracker(FlowTrackerConfig(preset=cfg.flow_preset, verbose=True))
    raise InputError(f"unknown tracker {cfg.tracker!r} (available: flow)")


def track_video(frames: np.ndarray, cfg: Track2DConfig, timings: dict | None = None) -> TrackResult:
    """Track a grid of ``grid_stride`` px from the first frame through the video."""
    t0 = time.perf_counter()
    T, H, W = frames.shape[:3]
    tracker = make_tracker(cfg)
    res = tracker.track(frames, grid_queries(0, H, W, cfg.grid_stride))
    if timings is not None:
        timings["track2d"] = time.perf_counter() - t0
    return res
