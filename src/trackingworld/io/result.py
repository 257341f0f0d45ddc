"""The result contract: ``DIR/result.npz``, ``DIR/poses_tum.txt``, ``DIR/config.json``.

Keys of ``result.npz`` (N tracks, T frames, H x W input resolution):

=============  =======  ===========  ==================================================================
key            dtype    shape        meaning
=============  =======  ===========  ==================================================================
tracks_2d      float32  [N,T,2]      pixel x, y at the input resolution (also where not visible)
visible        bool     [N,T]        observed in that frame (a static track's frames off its 3D point: not visible)
tracks_3d      float32  [N,T,3]      world coordinates, metres (estimate through occlusion too)
query_frame    int32    [N]          frame the track was started from
is_dynamic     bool     [N]          track belongs to a moving object
colors         uint8    [N,3]        RGB at the query frame
poses_c2w      float32  [T,4,4]      camera-to-world, last row 0 0 0 1
intrinsics     float32  [3,3]        pinhole K at the input resolution
depth          float32  [T,H,W]      temporally consistent video depth, metres
label_step     int8     [N]          optional: the step of the lifting that set is_dynamic (an index
                                     into ``optim.label_steps.LABEL_STEPS``; 0: the masks' label)
object_id      int32    [N]          optional: the rigid object whose motion placed the track (an index
                                     into object_poses; -1: none, every static track among them)
object_poses   float32  [G,T,4,4]    optional: each rigid object's object-to-world pose per frame (world
                                     metres; NaN in the frames its motion is not solved in). The object
                                     frame is a camera frame of the object's reference frame, so a track
                                     of object g sits at ``object_poses[g, t] @ p`` for one point ``p``
=============  =======  ===========  ==================================================================
"""

from __future__ import annotations

import os
from dataclasses import MISSING, dataclass, fields
from pathlib import Path

import numpy as np

from trackingworld.errors import InputError
from trackingworld.geometry import quat_wxyz
from trackingworld.io.arrays import read_arrays
from trackingworld.io.atomic import atomic_path, write_npz

RESULT_FILE = "result.npz"
TUM_FILE = "poses_tum.txt"
CONFIG_FILE = "config.json"


@dataclass
class Result:
    tracks_2d: np.ndarray
    visible: np.ndarray
    tracks_3d: np.ndarray
    query_frame: np.ndarray
    is_dynamic: np.ndarray
    colors: np.ndarray
    poses_c2w: np.ndarray
    intrinsics: np.ndarray
    depth: np.ndarray
    label_step: np.ndarray | None = None  # not written by the camera-centric baseline
    object_id: np.ndarray | None = None  # not written by the baseline, nor before stop 82
    object_poses: np.ndarray | None = None  # ... with object_id

    DTYPES = {
        "tracks_2d": np.float32,
        "visible": np.bool_,
        "tracks_3d": np.float32,
        "query_frame": np.int32,
        "is_dynamic": np.bool_,
        "colors": np.uint8,
        "poses_c2w": np.float32,
        "intrinsics": np.float32,
        "depth": np.float32,
        "label_step": np.int8,
        "object_id": np.int32,
        "object_poses": np.float32,
    }

    def __post_init__(self) -> None:
        for f in fields(self):
            if getattr(self, f.name) is not None:
                setattr(self, f.name, np.ascontiguousarray(getattr(self, f.name), dtype=self.DTYPES[f.name]))
        self.poses_c2w[:, 3, :] = (0.0, 0.0, 0.0, 1.0)
        self.validate()

    @property
    def num_tracks(self) -> int:
        return self.tracks_2d.shape[0]

    @property
    def num_frames(self) -> int:
        return self.poses_c2w.shape[0]

    def validate(self) -> None:
        """Check shapes against each other and that every position is finite."""
        N, T = self.visible.shape
        _, H, W = self.depth.shape
        expect = {
            "tracks_2d": (N, T, 2),
            "tracks_3d": (N, T, 3),
            "query_frame": (N,),
            "is_dynamic": (N,),
            "colors": (N, 3),
            "poses_c2w": (T, 4, 4),
            "intrinsics": (3, 3),
            "depth": (T, H, W),
            "label_step": (N,),
            "object_id": (N,),
        }
        for k, shape in expect.items():
            if getattr(self, k) is None:
                continue
            got = getattr(self, k).shape
            if got != shape:
                raise ValueError(f"result field {k} has shape {got}, expected {shape}")
        for k in ("tracks_2d", "tracks_3d", "poses_c2w", "intrinsics", "depth"):
            if not np.isfinite(getattr(self, k)).all():
                raise ValueError(f"result field {k} holds non-finite values")
        if N and (self.query_frame.min() < 0 or self.query_frame.max() >= T):
            raise ValueError("result field query_frame out of range")
        if (self.object_id is None) != (self.object_poses is None):
            raise ValueError("result fields object_id and object_poses come together")
        if self.object_poses is not None:
            G = len(self.object_poses)
            if self.object_poses.shape != (G, T, 4, 4):
                raise ValueError(f"result field object_poses has shape {self.object_poses.shape}, expected "
                                 f"({G}, {T}, 4, 4)")
            if N and (self.object_id.min() < -1 or self.object_id.max() >= G):
                raise ValueError(f"result field object_id out of range (-1 to {G - 1})")
            if np.isinf(self.object_poses).any():
                raise ValueError("result field object_poses holds infinite values")

    # the stop that first wrote each optional field: a result written before it (or by the baseline) has none
    OPTIONAL_SINCE = {"label_step": 76, "object_id": 82, "object_poses": 82}

    def require(self, name: str, option: str) -> np.ndarray:
        """The optional field ``name``, or an :class:`InputError` saying that ``option`` (the flag that needs it)
        cannot be served by this result."""
        value = getattr(self, name)
        if value is None:
            raise InputError(f"{option}: this result has no {name} (a baseline run, or one written before stop "
                             f"{self.OPTIONAL_SINCE[name]})")
        return value

    def as_dict(self) -> dict[str, np.ndarray]:
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}


def tum_lines(poses_c2w: np.ndarray, frames: np.ndarray | None = None) -> str:
    """TUM trajectory text (``t tx ty tz qx qy qz qw``) of poses ``[n,4,4]``, timestamp = frame index (``frames
    [n]``, None: 0 .. n-1)."""
    q = quat_wxyz(poses_c2w[:, :3, :3].astype(np.float64))
    rows = []
    stamps = range(len(poses_c2w)) if frames is None else frames
    for i, T, qq in zip(stamps, poses_c2w, q, strict=True):
        t = T[:3, 3]
        rows.append(f"{i:d} {t[0]:.9f} {t[1]:.9f} {t[2]:.9f} {qq[1]:.9f} {qq[2]:.9f} {qq[3]:.9f} {qq[0]:.9f}")
    return "\n".join(rows) + "\n"


def save_result(out_dir: str | os.PathLike, result: Result) -> Path:
    """Write ``result.npz`` and ``poses_tum.txt`` atomically; returns the npz path."""
    out_dir = Path(out_dir)
    result.validate()
    path = out_dir / RESULT_FILE
    write_npz(path, **result.as_dict())
    with atomic_path(out_dir / TUM_FILE) as tmp:
        tmp.write_text(tum_lines(result.poses_c2w))
    return path


def load_result(path: str | os.PathLike) -> Result:
    """Read a result folder (or its ``result.npz``) back into a :class:`Result`."""
    path = Path(path)
    if path.is_dir():
        path = path / RESULT_FILE
    if not path.exists():
        raise InputError(f"{path}: no such result file")
    z = read_arrays(path, "result")
    # the fields with a default (None) are optional
    missing = [f.name for f in fields(Result) if f.name not in z and f.default is MISSING]
    if missing:
        raise InputError(f"{path}: not a trackingworld result (missing keys: {', '.join(missing)})")
    return Result(**{f.name: z[f.name] for f in fields(Result) if f.name in z})
