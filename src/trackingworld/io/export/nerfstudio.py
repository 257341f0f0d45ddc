"""nerfstudio ``transforms.json`` (frames, intrinsics, OpenGL camera-to-world), with depth maps and the static
points as the initial point cloud.

nerfstudio reads camera-to-world in OpenGL axes (x right, y up, z back): this package's OpenCV poses are
multiplied on the right by diag(1, -1, -1, 1). Depth goes to 16-bit PNG with ``depth_unit_scale_factor``
metres per unit.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from trackingworld.io.result import Result

CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])


def gl_pose(pose_c2w_cv: np.ndarray) -> np.ndarray:
    return np.asarray(pose_c2w_cv, np.float64) @ CV_TO_GL


def write_nerfstudio(res: Result, folder: Path, image_names: list[str] | None, ply_name: str | None) -> dict:
    """Write ``transforms.json`` and ``depth/*.png`` into ``folder``; images (``images/``) and the point cloud
    are written by the caller and named here."""
    import cv2

    T = res.num_frames
    H, W = res.depth.shape[1:]
    K = res.intrinsics
    dmax = float(res.depth.max()) if res.depth.size else 1.0
    unit = max(1e-3, dmax / 65000.0)  # millimetres unless the scene is deeper than 65 m (arbitrary-scale depth)
    (folder / "depth").mkdir(parents=True, exist_ok=True)
    frames = []
    for t in range(T):
        d = np.clip(np.rint(res.depth[t] / unit), 0, 65535).astype(np.uint16)
        dname = f"depth/frame_{t:05d}.png"
        cv2.imwrite(str(folder / dname), d)
        fr = {"file_path": image_names[t] if image_names else f"images/frame_{t:05d}.jpg",
              "transform_matrix": gl_pose(res.poses_c2w[t]).tolist(), "depth_file_path": dname}
        frames.append(fr)
    meta = {"camera_model": "OPENCV", "fl_x": float(K[0, 0]), "fl_y": float(K[1, 1]), "cx": float(K[0, 2]),
            "cy": float(K[1, 2]), "w": int(W), "h": int(H), "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
            "depth_unit_scale_factor": unit, "frames": frames}
    if ply_name:
        meta["ply_file_path"] = ply_name
    (folder / "transforms.json").write_text(json.dumps(meta, indent=2) + "\n")
    return {"frames": T, "depth_unit_scale_factor": unit}
