"""Rendering frames and exact ground truth (depth, instances, point tracks) from a :class:`Scene`."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from trackingworld.geometry import invert_pose, project, transform
from trackingworld.synth.raycast import camera_rays, cast, shade
from trackingworld.synth.scene import Scene


@dataclass
class Rendering:
    frames: np.ndarray  # [T,H,W,3] uint8
    depth: np.ndarray  # [T,H,W] float32 metres (camera z)
    instance: np.ndarray  # [T,H,W] int16, primitive index
    local: np.ndarray  # [T,H,W,3] float32, hit point in the primitive's frame


def pixel_grid(W: int, H: int) -> np.ndarray:
    """All pixel centres ``[H*W,2]`` (x, y), row-major."""
    ys, xs = np.mgrid[0:H, 0:W]
    return np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float64)


def render(scene: Scene, progress=None) -> Rendering:
    cfg = scene.config
    H, W, T = cfg.height, cfg.width, cfg.frames
    uv = pixel_grid(W, H)
    frames = np.zeros((T, H, W, 3), np.uint8)
    depth = np.zeros((T, H, W), np.float32)
    inst = np.zeros((T, H, W), np.int16)
    local = np.zeros((T, H, W, 3), np.float32)
    for t in range(T):
        o, d = camera_rays(scene, t, uv)
        s, idx, lp, n = cast(scene, t, o, d)
        rgb = shade(scene, idx, lp, n).reshape(H, W, 3)
        # a light blur stands in for a camera's optics and removes aliasing of the finest texture octave
        rgb = cv2.GaussianBlur(rgb.astype(np.float32), (0, 0), 0.6)
        frames[t] = np.clip(rgb * 255 + 0.5, 0, 255).astype(np.uint8)
        depth[t] = s.reshape(H, W)
        inst[t] = idx.reshape(H, W)
        local[t] = lp.reshape(H, W, 3)
        if progress:
            progress(t + 1, T)
    return Rendering(frames, depth, inst, local)


def follow_points(scene: Scene, prim: np.ndarray, local: np.ndarray, frames=None):
    """Exact motion of surface points given by primitive index ``[N]`` and local point ``[N,3]``.

    Returns world xyz ``[N,T',3]``, pixels ``[N,T',2]`` and visibility ``[N,T']`` for ``frames``
    (all frames by default). A point is visible when it lies in front of the camera, inside the image and
    the ray through its pixel hits the same surface point first (exact occlusion test).
    """
    cfg = scene.config
    frames = range(scene.T) if frames is None else list(frames)
    N = prim.shape[0]
    xyz = np.zeros((N, len(frames), 3))
    uv = np.zeros((N, len(frames), 2))
    vis = np.zeros((N, len(frames)), bool)
    poses = np.stack([p.poses for p in scene.prims])  # [P,T,4,4]
    for j, t in enumerate(frames):
        w = transform(poses[prim, t], local)
        xyz[:, j] = w
        uvj, z = project(transform(invert_pose(scene.poses_c2w[t]), w), scene.K)
        uv[:, j] = uvj
        inside = (z > 1e-3) & (uvj[:, 0] >= -0.5) & (uvj[:, 0] < cfg.width - 0.5)
        inside &= (uvj[:, 1] >= -0.5) & (uvj[:, 1] < cfg.height - 0.5)
        if inside.any():
            o, d = camera_rays(scene, t, uvj[inside])
            s, idx, _, _ = cast(scene, t, o, d)
            ok = (idx == prim[inside]) & (np.abs(s - z[inside]) < 1e-4 * z[inside] + 1e-4)
            vis[inside, j] = ok
    return xyz, uv, vis
