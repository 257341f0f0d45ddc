"""Binary little-endian PLY point clouds: x, y, z (float32, world metres), red, green, blue (uchar) and
dynamic (uchar, 1 on a moving object). Written with numpy's structured arrays: the header is a few lines and a
library would add a dependency for nothing."""

from __future__ import annotations

from pathlib import Path

import numpy as np

PLY_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
                      ("dynamic", "u1")])


def write_ply(path: Path, xyz: np.ndarray, rgb: np.ndarray, dynamic: np.ndarray | None = None) -> None:
    """Write points ``xyz`` [M,3] with colours ``rgb`` [M,3] uint8 and flags ``dynamic`` [M] bool."""
    v = np.empty(len(xyz), PLY_DTYPE)
    v["x"], v["y"], v["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    v["red"], v["green"], v["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    v["dynamic"] = 0 if dynamic is None else dynamic.astype(np.uint8)
    header = ("ply\nformat binary_little_endian 1.0\ncomment trackingworld\n"
              f"element vertex {len(xyz)}\n"
              + "".join(f"property {'float' if n in 'xyz' else 'uchar'} {n}\n" for n in PLY_DTYPE.names)
              + "end_header\n")
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(v.tobytes())
