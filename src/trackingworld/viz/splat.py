"""A small software point renderer (z-buffered square splats) and virtual camera paths, for the 3D video.

Written by hand because the renderer must run headless on a CPU with nothing but numpy and OpenCV: pyrender,
open3d and the like need an OpenGL context. Points are drawn nearest-first per pixel, which is all a dense
track cloud needs.
"""

from __future__ import annotations

import cv2
import numpy as np

from trackingworld.geometry import invert_pose, look_at, project, transform


def splat(points: np.ndarray, colors: np.ndarray, pose_c2w: np.ndarray, K: np.ndarray, size: tuple[int, int],
          radius: int = 1, background=(255, 255, 255), image: np.ndarray | None = None) -> np.ndarray:
    """Render world points ``[M,3]`` with colours ``[M,3]`` uint8 seen from ``pose_c2w`` with pinhole ``K``.

    ``size`` is (W, H); each point covers a (2*radius+1)^2 square, nearest point wins per pixel. Draws over
    ``image`` [H,W,3] when given. Returns [H,W,3] uint8."""
    W, H = size
    out = np.empty((H, W, 3), np.uint8) if image is None else image.copy()
    if image is None:
        out[:] = background
    if len(points) == 0:
        return out
    cam = transform(invert_pose(np.asarray(pose_c2w, np.float64)), np.asarray(points, np.float64))
    uv, z = project(cam, K)
    ok = (z > 1e-6) & np.isfinite(uv).all(1)
    u = np.rint(uv[ok, 0]).astype(np.int64)
    v = np.rint(uv[ok, 1]).astype(np.int64)
    z, col = z[ok], np.asarray(colors)[ok]
    offs = np.arange(-radius, radius + 1)
    du, dv = np.meshgrid(offs, offs)
    uu = (u[:, None] + du.ravel()).ravel()
    vv = (v[:, None] + dv.ravel()).ravel()
    zz = np.repeat(z, du.size)
    src = np.repeat(np.arange(len(z)), du.size)
    inside = (uu >= 0) & (uu < W) & (vv >= 0) & (vv < H)
    pix = vv[inside] * W + uu[inside]
    zz, src = zz[inside], src[inside]
    order = np.lexsort((zz, pix))  # by pixel, then nearest first
    first = np.unique(pix[order], return_index=True)[1]
    win = order[first]
    out.reshape(-1, 3)[pix[win]] = col[src[win]]
    return out


def draw_polyline(image: np.ndarray, points: np.ndarray, pose_c2w: np.ndarray, K: np.ndarray, color,
                  thickness: int = 2) -> None:
    """Draw world points ``[M,3]`` as a polyline (in place), skipping segments behind the camera."""
    cam = transform(invert_pose(np.asarray(pose_c2w, np.float64)), np.asarray(points, np.float64))
    uv, z = project(cam, K)
    for a in range(len(points) - 1):
        if z[a] > 1e-3 and z[a + 1] > 1e-3:
            p, q = uv[a], uv[a + 1]
            if np.all(np.abs(np.concatenate([p, q])) < 1e5):
                cv2.line(image, (int(p[0]), int(p[1])), (int(q[0]), int(q[1])), color, thickness, cv2.LINE_AA)


def frustum_lines(pose_c2w: np.ndarray, K: np.ndarray, size: tuple[int, int], scale: float) -> np.ndarray:
    """World line segments ``[8,2,3]`` of a camera frustum whose image plane sits ``scale`` metres ahead."""
    W, H = size
    corners = np.array([[0, 0], [W, 0], [W, H], [0, H]], np.float64)
    rays = np.c_[(corners[:, 0] - K[0, 2]) / K[0, 0], (corners[:, 1] - K[1, 2]) / K[1, 1], np.ones(4)] * scale
    world = transform(np.asarray(pose_c2w, np.float64), rays)
    c = np.asarray(pose_c2w, np.float64)[:3, 3]
    segs = [(c, w) for w in world] + [(world[i], world[(i + 1) % 4]) for i in range(4)]
    return np.array(segs)


def orbit_poses(poses_c2w: np.ndarray, target: np.ndarray, distance: float, T: int, swing_deg: float = 30.0,
                elevation_deg: float = 20.0) -> np.ndarray:
    """Virtual cameras ``[T,4,4]`` that look at ``target`` from ``distance`` metres, swinging
    +-``swing_deg`` about the world up (the first input camera's -y) once over the video, raised by
    ``elevation_deg`` above the first camera's viewing direction."""
    P0 = np.asarray(poses_c2w[0], np.float64)
    up = -P0[:3, 1]
    back = -P0[:3, 2]
    side = np.cross(up, back)
    out = []
    el = np.deg2rad(elevation_deg)
    for i in range(T):
        a = np.deg2rad(swing_deg) * np.sin(2 * np.pi * i / max(T, 1))
        d = np.cos(el) * (np.cos(a) * back + np.sin(a) * side) + np.sin(el) * up
        out.append(look_at(target + distance * d, target, up=up))
    return np.stack(out)


def follow_poses(poses_c2w: np.ndarray, distance: float, elevation_deg: float = 20.0) -> np.ndarray:
    """A third-person view of the estimated camera: each frame's pose pulled back ``distance`` metres and
    raised by ``elevation_deg``, looking at the point ``distance`` ahead of the camera."""
    out = []
    for P in np.asarray(poses_c2w, np.float64):
        up, fwd = -P[:3, 1], P[:3, 2]
        target = P[:3, 3] + distance * fwd
        el = np.deg2rad(elevation_deg)
        eye = target - 2 * distance * (np.cos(el) * fwd - np.sin(el) * up)
        out.append(look_at(eye, target, up=up))
    return np.stack(out)
