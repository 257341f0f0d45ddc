"""Camera-centric lifting: 2D tracks + per-frame depth -> 3D points in each frame's camera."""

from __future__ import annotations

import numpy as np

from trackingworld.geometry import unproject
from trackingworld.image import sample_image
from trackingworld.optim.parallel import each_frame


def sample_maps(maps: np.ndarray, uv: np.ndarray, visible: np.ndarray | None = None,
                fill: float = 1.0) -> np.ndarray:
    """Bilinear sample of ``maps [T,H,W]`` at ``uv [N,T,2]`` (border replicated) -> ``[N,T]`` float32.
    With ``visible [N,T]`` only the visible observations are sampled and the others are ``fill`` (finite, so
    that masked terms stay zero): a dense video's hidden entries of ``[N,T]`` outgrow the visible ones."""
    N, T = uv.shape[:2]
    if visible is None:
        per_frame = np.ascontiguousarray(uv.transpose(1, 0, 2), np.float32)  # [T,N,2]: one contiguous read a frame
        out = np.empty((T, N), np.float32)
        for t in range(T):
            out[t] = sample_image(maps[t].astype(np.float32), per_frame[t])
        return np.ascontiguousarray(out.T)
    out = np.full((T, N), fill, np.float32)  # frame-major while written: each frame its own contiguous row
    vis_t = np.ascontiguousarray(visible.T)

    def frame(t: int) -> None:
        v = np.flatnonzero(vis_t[t])
        out[t, v] = sample_image(maps[t].astype(np.float32), uv[v, t].astype(np.float32))

    each_frame(frame, range(T))  # on the CPUs' threads (OpenCV and numpy let go of the GIL): the same numbers
    return np.ascontiguousarray(out.T)


def lift_camera_frame(uv: np.ndarray, depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Tracks ``[N,T,2]`` + depth maps ``[T,H,W]`` -> camera-frame points ``[N,T,3]`` metres."""
    return unproject(uv, sample_maps(depth, uv), K).astype(np.float32)
