"""COLMAP text model: ``cameras.txt``, ``images.txt``, ``points3D.txt`` (and ``images/`` when frames exist).

One PINHOLE camera; one image per frame with its world-to-camera pose; one 3D point per exported static track
with an observation in every frame where the track is visible. COLMAP puts the centre of the top-left pixel at
(0.5, 0.5), this package at (0, 0): principal point and observations are shifted by half a pixel here.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trackingworld.geometry import invert_pose, project, quat_wxyz, transform
from trackingworld.io.result import Result

PIXEL_SHIFT = 0.5  # this package's pixel coordinates -> COLMAP's


def image_name(t: int) -> str:
    return f"frame_{t:05d}.jpg"


def write_colmap(res: Result, folder: Path, tracks: np.ndarray) -> dict:
    """Write the model of static tracks ``tracks`` [M] (indices into ``res``) into ``folder``."""
    T = res.num_frames
    H, W = res.depth.shape[1:]
    K = res.intrinsics.astype(np.float64)
    w2c = invert_pose(res.poses_c2w.astype(np.float64))
    q = quat_wxyz(w2c[:, :3, :3])
    qf = res.query_frame[tracks]
    xyz = res.tracks_3d[tracks, qf].astype(np.float64)  # a static track's one world position
    vis = res.visible[tracks]  # [M,T]
    uv = res.tracks_2d[tracks].astype(np.float64) + PIXEL_SHIFT
    # mean reprojection error of each point over its observations (COLMAP's ERROR column), pixels
    err = np.zeros(len(tracks))
    for t in range(T):
        on = vis[:, t]
        if on.any():
            p, _ = project(transform(w2c[t], xyz[on]), K)
            err[on] += np.linalg.norm(p + PIXEL_SHIFT - uv[on, t], axis=1)
    err /= np.maximum(vis.sum(1), 1)
    # point2D index of track m in frame t: its rank among the tracks visible in t
    p2d_idx = np.cumsum(vis, axis=0) - 1  # [M,T]
    folder.mkdir(parents=True, exist_ok=True)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2] + PIXEL_SHIFT, K[1, 2] + PIXEL_SHIFT
    (folder / "cameras.txt").write_text(
        "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
        f"# Number of cameras: 1\n1 PINHOLE {W} {H} {fx:.6f} {fy:.6f} {cx:.6f} {cy:.6f}\n")
    with open(folder / "images.txt", "w") as f:
        f.write("# Image list with two lines of data per image:\n"
                "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
                f"# Number of images: {T}\n")
        for t in range(T):
            tt = w2c[t, :3, 3]
            f.write(f"{t + 1} {q[t, 0]:.9f} {q[t, 1]:.9f} {q[t, 2]:.9f} {q[t, 3]:.9f} "
                    f"{tt[0]:.9f} {tt[1]:.9f} {tt[2]:.9f} 1 {image_name(t)}\n")
            on = np.flatnonzero(vis[:, t])
            rows = np.c_[uv[on, t], on + 1]
            f.write(" ".join(f"{x:.3f} {y:.3f} {int(i)}" for x, y, i in rows) + "\n")
    with open(folder / "points3D.txt", "w") as f:
        f.write("# 3D point list with one line of data per point:\n"
                "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
                f"# Number of points: {len(tracks)}\n")
        for m in range(len(tracks)):
            ts = np.flatnonzero(vis[m])
            track = " ".join(f"{t + 1} {p2d_idx[m, t]}" for t in ts)
            c = res.colors[tracks[m]]
            f.write(f"{m + 1} {xyz[m, 0]:.6f} {xyz[m, 1]:.6f} {xyz[m, 2]:.6f} {c[0]} {c[1]} {c[2]} "
                    f"{err[m]:.4f} {track}\n")
    return {"points": len(tracks), "observations": int(vis.sum()), "mean_reproj_px": float(err.mean())
            if len(err) else 0.0}
