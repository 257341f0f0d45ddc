"""``--method baseline``: the camera-centric baseline every later result is compared with.

2D tracks from the configured tracker, identity camera poses, and each frame's depth prior lifted in that
frame's camera: object and camera motion are not separated at all.
"""

from __future__ import annotations

import cv2
import numpy as np

from trackingworld.config import RunConfig
from trackingworld.geometry import nearest_pixel
from trackingworld.io.result import Result
from trackingworld.pipeline.inputs import Inputs, resize_stack
from trackingworld.pipeline.lift import lift_camera_frame, sample_maps
from trackingworld.tracking2d.base import TrackResult, hold_invisible


def run_baseline(inp: Inputs, tr: TrackResult, cfg: RunConfig, timings: dict | None = None,
                 report: dict | None = None) -> Result:
    T, h, w = inp.frames.shape[:3]
    W, H = inp.size_in
    depth = inp.depth if inp.depth is not None else np.ones((T, h, w), np.float32)
    xyz = lift_camera_frame(tr.tracks, depth, inp.K)
    xyz = hold_invisible(xyz, tr.visible)
    qt = tr.queries[:, 0].astype(np.int32)
    colors = sample_colors(inp.frames, tr.queries)
    mask_at_query = sample_maps(inp.masks.astype(np.float32), tr.tracks)[np.arange(len(qt)), qt] > 0.5
    depth_out = resize_stack(depth, W, H, cv2.INTER_LINEAR)
    return Result(
        tracks_2d=inp.to_input_pixels(tr.tracks), visible=tr.visible, tracks_3d=xyz, query_frame=qt,
        is_dynamic=mask_at_query, colors=colors, poses_c2w=np.tile(np.eye(4), (T, 1, 1)),
        intrinsics=inp.K_in, depth=depth_out,
    )


def sample_colors(frames: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """RGB ``[N,3]`` uint8 at the (rounded) query pixels."""
    x, y = nearest_pixel(queries[:, 1:3], frames.shape[2], frames.shape[1])
    return frames[queries[:, 0].astype(int), y, x]
