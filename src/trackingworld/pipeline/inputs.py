"""Loading and preparing a run's inputs: frames, depth prior, masks, intrinsics, processing resolution."""

from __future__ import annotations

import sys
from dataclasses import dataclass

import cv2
import numpy as np

from trackingworld.config import InputConfig
from trackingworld.errors import InputError
from trackingworld.geometry import default_intrinsics, scale_intrinsics
from trackingworld.io.frames import read_frames
from trackingworld.io.priors import (
    check_principal_point,
    fill_invalid_depth,
    load_depth,
    load_masks,
    parse_intrinsics,
    prior_fit,
)
from trackingworld.priors.sources import depth_source, intrinsics_given, mask_source
from trackingworld.progress import warn


@dataclass
class Inputs:
    """Everything at the processing resolution (h, w), plus what is needed to return to the input one.

    frames [T,h,w,3] uint8; depth [T,h,w] float32 metres (None until the priors are resolved, unless a file
    was given); masks [T,h,w] bool (all False until resolved, unless a file was given);
    K [3,3] at the processing resolution; size_in (W, H) of the input frames; depth_detail / depth_note what the
    depth prior can tell the lifting (:func:`trackingworld.priors.resolve.depth_detail`).
    """

    frames: np.ndarray
    depth: np.ndarray | None
    masks: np.ndarray
    K: np.ndarray
    size_in: tuple[int, int]
    K_in: np.ndarray
    fps: float | None = None
    # where the depth prior comes from, for what the lifting asks of it (priors.resolve.depth_detail): "given" (a
    # file); "estimated" (SfM, a depth model); "constant", no depth at all (--depth none, or SfM without parallax)
    depth_detail: str = "given"
    depth_note: str = ""  # why it is "constant", in words
    # where the masks come from: "objects" (a file, a segmentation model: each mover's whole silhouette, dilated),
    # "motion" (the weight-free motion masks: pixels whose motion the camera does not explain), "none"
    masks_detail: str = "objects"

    @property
    def scale(self) -> tuple[float, float]:
        """(sx, sy) from processing to input pixels."""
        return self.size_in[0] / self.frames.shape[2], self.size_in[1] / self.frames.shape[1]

    def to_input_pixels(self, uv: np.ndarray) -> np.ndarray:
        """Pixels ``[...,2]`` at the processing resolution -> the input's (pixel centres kept), float32; unchanged to
        the bit when the video is processed at its own size (``(x + 0.5) * 1 - 0.5`` in float32 is not always x)."""
        sx, sy = self.scale
        if sx == 1 and sy == 1:
            return np.array(uv, np.float32)  # a copy (one: a long video's [N,T,2] is gigabytes)
        out = np.empty(uv.shape, np.float32)
        out[..., 0] = (uv[..., 0] + 0.5) * sx - 0.5
        out[..., 1] = (uv[..., 1] + 0.5) * sy - 0.5
        return out


def resize_stack(arr: np.ndarray, w: int, h: int, interp: int) -> np.ndarray:
    """Resize every frame of ``[T,H,W(,C)]`` to (w, h)."""
    if arr.shape[2] == w and arr.shape[1] == h:
        return arr
    return np.stack([cv2.resize(a, (w, h), interpolation=interp) for a in arr])


MIN_SIDE_PX = 16  # the smallest processing resolution's side


def load_inputs(cfg: InputConfig, verbose: bool = True) -> Inputs:
    frames, fps = read_frames(cfg.input, cfg.max_frames, cfg.frame_stride)
    T, H, W = frames.shape[:3]
    if T < 2:
        raise InputError(f"{cfg.input}: need at least 2 frames, found {T}")
    depth = None
    if depth_source(cfg.depth) == "file":
        depth = load_depth(cfg.depth, T, cfg.frame_stride)
        # depth models often predict at their own size: resized, but not a rotated array
        warn(prior_fit(depth.shape, W, H, cfg.depth, "depth"), verbose, "inputs")
        depth = fill_invalid_depth(resize_stack(depth, W, H, cv2.INTER_LINEAR))
    masks = np.zeros((T, H, W), bool)
    if mask_source(cfg.masks) == "file":
        masks = load_masks(cfg.masks, T, cfg.frame_stride)
        warn(prior_fit(masks.shape, W, H, cfg.masks, "masks"), verbose, "inputs")
        masks = resize_stack(masks.astype(np.uint8), W, H, cv2.INTER_NEAREST) > 0
    if intrinsics_given(cfg.intrinsics):
        K_in = parse_intrinsics(cfg.intrinsics)
        check_principal_point(K_in, W, H, cfg.intrinsics)
    else:  # the priors may replace it (a depth model's focal length)
        K_in = default_intrinsics(W, H, cfg.default_fov_deg)
    w, h = W, H
    if cfg.resize and max(W, H) > cfg.resize:
        s = cfg.resize / max(W, H)
        w, h = max(2, round(W * s)), max(2, round(H * s))
    if min(w, h) < MIN_SIDE_PX:  # OpenCV's DIS flow refuses smaller images deep inside the tracking
        raise InputError(f"{cfg.input}: processing at {w}x{h} px is too small: the tracking needs {MIN_SIDE_PX} px or "
                         f"more on each side ({'a larger --resize' if (w, h) != (W, H) else 'a larger video'})")
    K = scale_intrinsics(K_in, w / W, h / H)
    frames_p = resize_stack(frames, w, h, cv2.INTER_AREA)
    depth_p = None if depth is None else resize_stack(depth, w, h, cv2.INTER_LINEAR)
    masks_p = resize_stack(masks.astype(np.uint8), w, h, cv2.INTER_NEAREST) > 0
    if verbose:
        print(f"[inputs] {T} frames {W}x{H}, processing at {w}x{h}", file=sys.stderr)
    return Inputs(frames_p, depth_p, masks_p, K, (W, H), K_in, fps)
