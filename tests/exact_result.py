"""An exact small result (no optimisation): a textured wall and floor of static points, a cube moving across,
a camera translating and turning; frames rendered by splatting, a ``config.json`` pointing at them. Used by the
viewer, render and export tests, whose round trips then compare against known numbers."""

from __future__ import annotations

import json
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from trackingworld.geometry import default_intrinsics, invert_pose, look_at, project, transform
from trackingworld.io.result import Result, save_result
from trackingworld.viz.splat import splat

T, W, H = 8, 96, 64


def exact_result(seed: int = 0) -> tuple[Result, np.ndarray]:
    rng = np.random.default_rng(seed)
    K = default_intrinsics(W, H, 60.0)
    poses = np.stack([look_at(np.array([0.1 * t, -0.2 - 0.01 * t * (T - 1 - t), 0.05 * t]), np.array([0.3, 0.0, 5.0]))
                      for t in range(T)])
    wall = np.c_[rng.uniform(-3, 3, 900), rng.uniform(-2, 1, 900), np.full(900, 5.0)]
    floor = np.c_[rng.uniform(-3, 3, 600), np.full(600, 1.0), rng.uniform(1.5, 5, 600)]
    static = np.r_[wall, floor]
    cube0 = rng.uniform(-0.3, 0.3, (200, 3)) + [-1.0, 0.3, 3.0]
    motion = np.linspace(0, 1.5, T)[:, None] * np.array([1.0, 0.0, 0.0])  # [T,3]
    N_s, N_d = len(static), len(cube0)
    xyz = np.concatenate([np.repeat(static[:, None], T, 1), cube0[:, None] + motion[None]], 0)  # [N,T,3]
    dyn = np.r_[np.zeros(N_s, bool), np.ones(N_d, bool)]
    colors = np.r_[rng.integers(40, 200, (N_s, 3)), np.tile([[230, 60, 40]], (N_d, 1))].astype(np.uint8)
    cam = transform(invert_pose(poses)[None], xyz)  # [N,T,3]
    uv, z = project(cam, K)
    visible = (z > 0.1) & (uv[..., 0] >= 0) & (uv[..., 0] <= W - 1) & (uv[..., 1] >= 0) & (uv[..., 1] <= H - 1)
    frames = np.stack([splat(xyz[:, t], colors, poses[t], K, (W, H), radius=2, background=(20, 20, 20))
                       for t in range(T)])
    depth = np.full((T, H, W), 5.0, np.float32)
    qf = np.argmax(visible, axis=1).astype(np.int32)
    res = Result(tracks_2d=uv, visible=visible, tracks_3d=xyz, query_frame=qf, is_dynamic=dyn, colors=colors,
                 poses_c2w=poses, intrinsics=K, depth=depth)
    return res, frames


def write_exact_result(folder: Path) -> tuple[Result, np.ndarray]:
    """Save the result and its frames (``folder/frames/*.png``) with a config.json naming them."""
    res, frames = exact_result()
    (folder / "frames").mkdir(parents=True, exist_ok=True)
    for t, f in enumerate(frames):
        iio.imwrite(folder / "frames" / f"{t:04d}.png", f)
    save_result(folder, res)
    (folder / "config.json").write_text(json.dumps({"inputs": {"input": str(folder / "frames"),
                                                               "frame_stride": 1, "max_frames": None}}))
    return res, frames
