"""TAPVid-3D style npz: ``tracks_XYZ`` [T,N,3] camera coordinates (metres, OpenCV axes), ``visibility`` [T,N]
bool, ``queries_xyt`` [N,3] (pixel x, pixel y, query frame), ``fx_fy_cx_cy`` [4]. Time-major, as the
TAPVid-3D release stores it; positions are given through occlusion too (as estimated)."""

from __future__ import annotations

import numpy as np

from trackingworld.geometry import invert_pose
from trackingworld.io.result import Result


def tapvid3d_arrays(res: Result, tracks: np.ndarray) -> dict[str, np.ndarray]:
    w2c = invert_pose(res.poses_c2w.astype(np.float64))  # [T,4,4]
    xyz = res.tracks_3d[tracks].astype(np.float64)  # [N,T,3]
    cam = np.einsum("tij,ntj->tni", w2c[:, :3, :3], xyz) + w2c[:, None, :3, 3]
    qf = res.query_frame[tracks]
    uv = res.tracks_2d[tracks, qf]
    K = res.intrinsics
    return {"tracks_XYZ": cam.astype(np.float32), "visibility": res.visible[tracks].T.copy(),
            "queries_xyt": np.c_[uv, qf].astype(np.float32),
            "fx_fy_cx_cy": np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]], np.float32)}
