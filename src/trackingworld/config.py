"""Typed configuration of a run. Defaults are the paper's values unless a comment says otherwise."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field


@dataclass
class InputConfig:
    input: str = ""
    depth: str | None = None  # .npy/.npz metres or a folder of 16-bit PNG millimetres
    masks: str | None = None  # folder of PNGs (non-zero = dynamic) or .npy bool [T,H,W]
    intrinsics: str | None = None  # text file (3x3 or fx,fy,cx,cy) or inline "fx,fy,cx,cy"
    max_frames: int | None = None
    frame_stride: int = 1
    resize: int | None = None  # long side of the processing resolution (outputs stay at input size)
    default_fov_deg: float = 60.0  # used when no intrinsics are given


@dataclass
class Track2DConfig:
    tracker: str = "flow"  # flow (weight-free) | file (precomputed, see tracks_file)
    tracks_file: str | None = None  # CoTracker / TAPNet layout .npz, see trackingworld.io.tracks
    grid_stride: int = 4  # s in the paper (Sec. 3.2)
    query_stride: int = 1  # every frame is a query frame (the authors' code: 10)
    first_frame_only: bool = False  # ablation "w/o T.E.F"
    cover_radius: float = 1.0  # r: covered when a visible track lies within r px (0: rounding, as the authors)
    min_component: int = 50  # tau
    dense_mode: str = "upsample"  # upsample (grid + convex upsampler) | direct (every pixel tracked)
    upsampler: str = "convex"  # convex | bilinear
    flow_preset: str = "fine"


@dataclass
class RunConfig:
    method: str = "baseline"
    device: str = "cpu"
    seed: int = 0
    inputs: InputConfig = field(default_factory=InputConfig)
    track2d: Track2DConfig = field(default_factory=Track2DConfig)

    def to_dict(self) -> dict:
        return asdict(self)
