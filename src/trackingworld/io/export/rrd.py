"""A rerun recording (``.rrd``), for ``rerun result.rrd``: timeline ``frame``; ``world`` in OpenCV axes (RDF);
``world/static_map`` (static points, logged once); per frame ``world/points`` (tracks visible in that frame,
dynamic ones tinted), ``world/dynamic_trails``, ``world/camera`` (pose and pinhole) with ``world/camera/image``
(JPEG) and ``world/camera_path`` so far."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trackingworld.errors import InputError
from trackingworld.io.result import Result
from trackingworld.viz import display as D


def write_rrd(res: Result, path: Path, frames: np.ndarray | None, order: np.ndarray, max_points: int,
              progress=None) -> dict:
    try:
        import rerun as rr
    except ImportError as e:
        raise InputError("--format rrd needs rerun-sdk: pip install rerun-sdk") from e
    T = res.num_frames
    H, W = res.depth.shape[1:]
    rec = rr.RecordingStream("trackingworld")
    rec.save(str(path))
    rec.log("world", rr.ViewCoordinates.RDF, static=True)
    sidx, sxyz = D.static_map(res.tracks_3d, res.query_frame, res.is_dynamic, order, max_points)
    rec.log("world/static_map", rr.Points3D(sxyz, colors=res.colors[sidx]), static=True)
    trail_idx = D.trail_indices(res.is_dynamic, res.visible, order, 300)
    centres = res.poses_c2w[:, :3, 3]
    n_points = 0
    for t in range(T):
        rec.set_time("frame", sequence=t)
        idx, pts, col = D.frame_points(res, t, order, max_points, "video + dynamic tint",
                                       None if frames is None else frames[t])
        rec.log("world/points", rr.Points3D(pts, colors=col))
        n_points += len(idx)
        seg, _ = D.trail_segments(res.tracks_3d, trail_idx, t, 12, res.visible)
        rec.log("world/dynamic_trails", rr.LineStrips3D(seg, colors=D.DYNAMIC_COLOR))
        P = res.poses_c2w[t]
        rec.log("world/camera", rr.Transform3D(translation=P[:3, 3], mat3x3=P[:3, :3]))
        rec.log("world/camera", rr.Pinhole(image_from_camera=res.intrinsics, resolution=[W, H]))
        if frames is not None:
            rec.log("world/camera/image", rr.Image(frames[t]).compress(jpeg_quality=85))
        rec.log("world/camera_path", rr.LineStrips3D([centres[: t + 1]], colors=[40, 40, 40]))
        if progress:
            progress(t + 1)
    rec.flush()
    rec.disconnect()
    return {"frames": T, "static_points": len(sidx), "frame_points": n_points}
