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
    tracker: str = "flow"
    grid_stride: int = 4  # s in the paper (Sec. 3.2)
    flow_preset: str = "medium"


@dataclass
class RunConfig:
    method: str = "baseline"
    device: str = "cpu"
    seed: int = 0
    inputs: InputConfig = field(default_factory=InputConfig)
    track2d: Track2DConfig = field(default_factory=Track2DConfig)

    def to_dict(self) -> dict:
        return asdict(self)
