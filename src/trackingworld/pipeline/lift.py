"""Camera-centric lifting: 2D tracks + per-frame depth -> 3D points in each frame's camera."""

from __future__ import annotations

import numpy as np

from trackingworld.geometry import unproject
from trackingworld.image import sample_image
from trackingworld.optim.parallel import each_frame


def sample_maps(maps: np.ndarray, uv: np.ndarray, visible: np.ndarray | None = None,
                fill: float = 1.0, out: np.ndarray | None = None) -> np.ndarray:
    """Bilinear sample of ``maps [T,H,W]`` at ``uv [N,T,2]`` (border replicated) -> ``[N,T]`` float32.
    With ``visible [N,T]`` only the visible observations are sampled and the others are ``fill`` (finite, so
    that masked terms stay zero): a dense video's hidden entries of ``[N,T]`` outgrow the visible ones. ``out``
    ``[N,T]`` float32 (with ``visible``): the samples written into it at the visible observations, the others left
    as they are (no new ``[N,T]`` array); returned."""
    N, T = uv.shape[:2]
    if visible is None:
        if out is not None:
            raise ValueError("sample_maps: out needs visible")
        per_frame = np.ascontiguousarray(uv.transpose(1, 0, 2), np.float32)  # [T,N,2]: one contiguous read a frame
        dense = np.empty((T, N), np.float32)
        for t in range(T):
            dense[t] = sample_image(maps[t].astype(np.float32), per_frame[t])
        return np.ascontiguousarray(dense.T)
    if out is None:  # written in place, a column a frame: one [N,T] array (no frame-major one transposed after it)
        out = np.full((N, T), fill, np.float32)
    vis_t = np.ascontiguousarray(visible.T)

    def frame(t: int) -> None:
        v = np.flatnonzero(vis_t[t])
        out[v, t] = sample_image(maps[t].astype(np.float32), uv[v, t].astype(np.float32))

    each_frame(frame, range(T))  # on the CPUs' threads (OpenCV and numpy let go of the GIL): the same numbers
    return out


def sample_observations(maps: np.ndarray, uv: np.ndarray, n: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``maps [T,H,W]`` sampled bilinearly (border replicated) at the observations ``(n [R], t [R])`` of the tracks
    ``uv [N,T,2]`` px -> ``[R]`` float32: the numbers :func:`sample_maps` gives there, without its ``[N,T]`` array
    (the video depth reads the prior at its thinned references only: 120 frames, 257k tracks, 0.28 -> 0.025 s).
    Frame by frame, the observations in any order."""
    out = np.empty(len(n), np.float32)
    order = np.argsort(t, kind="stable")
    bounds = np.searchsorted(t[order], np.arange(maps.shape[0] + 1))

    def frame(f: int) -> None:
        o = order[bounds[f]:bounds[f + 1]]
        if len(o):
            out[o] = sample_image(maps[f].astype(np.float32), uv[n[o], f].astype(np.float32))

    each_frame(frame, range(maps.shape[0]))
    return out


def lift_camera_frame(uv: np.ndarray, depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Tracks ``[N,T,2]`` + depth maps ``[T,H,W]`` -> camera-frame points ``[N,T,3]`` metres."""
    return unproject(uv, sample_maps(depth, uv), K).astype(np.float32)
