"""A weight-free tracker: OpenCV DIS optical flow between consecutive frames, chained over time in both
directions from each query frame, with forward-backward consistency as the occlusion test."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from trackingworld.progress import Progress
from trackingworld.tracking2d.base import TrackResult


@dataclass
class FlowTrackerConfig:
    preset: str = "fine"  # DIS preset: ultrafast | fast | medium | fine
    fb_abs_px: float = 2.0  # forward-backward error allowed: abs + rel * |flow|
    fb_rel: float = 0.05
    max_gap: int = 16  # frames a point may stay unobserved before it is lost for good
    verbose: bool = False


def _dis(preset: str):
    """OpenCV DIS flow. ``fine`` is the ``medium`` preset at full resolution with denser patches."""
    presets = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
               "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM, "fine": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}
    if preset not in presets:
        raise ValueError(f"unknown DIS preset {preset!r} (choose from {', '.join(presets)})")
    dis = cv2.DISOpticalFlow_create(presets[preset])
    if preset == "fine":
        dis.setFinestScale(0)
        dis.setPatchStride(3)
        dis.setGradientDescentIterations(40)
        dis.setVariationalRefinementIterations(10)
    return dis


def pairwise_flows(frames: np.ndarray, preset: str = "fine", verbose: bool = False):
    """Forward flows ``fwd[t]`` (t -> t+1) and backward flows ``bwd[t]`` (t+1 -> t), each [T-1,H,W,2]."""
    gray = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames]
    dis = _dis(preset)
    T = len(gray)
    fwd = np.zeros((max(T - 1, 0),) + gray[0].shape + (2,), np.float32)
    bwd = np.zeros_like(fwd)
    bar = Progress("track2d: optical flow pair", T - 1, verbose)
    for t in range(T - 1):
        fwd[t] = dis.calc(gray[t], gray[t + 1], None)
        bwd[t] = dis.calc(gray[t + 1], gray[t], None)
        bar.update(t + 1)
    return fwd, bwd


def sample_image(img: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Bilinear sample of ``img [H,W(,C)]`` at ``pts [M,2]`` (border replicated) -> ``[M(,C)]``.

    OpenCV's remap takes maps below 32767 per side, so points are laid out in rows of 1024."""
    M = len(pts)
    cols = 1024
    rows = max(1, -(-M // cols))
    m = np.zeros((rows * cols, 2), np.float32)
    m[:M] = pts
    m = m.reshape(rows, cols, 2)
    out = cv2.remap(img, m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape((rows * cols,) + img.shape[2:])[:M]


def sample_flow(flow: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Bilinear sample of ``flow [H,W,2]`` at ``pts [M,2]``."""
    return sample_image(flow, pts)


class FlowTracker:
    """Chained optical flow with occlusion handling, in both directions of time from each query frame.

    A step is observed when the forward-backward check passes and the point stays in the image. Through a
    failed step the point moves with its last observed velocity (the estimate through occlusion) and is
    marked not visible; it is observed again when the check passes and the flow agrees with that velocity.
    After ``max_gap`` failed steps in a row, or once it leaves the image, it is lost for good.
    """

    def __init__(self, config: FlowTrackerConfig | None = None):
        self.config = config or FlowTrackerConfig()
        self._cache: tuple[int, np.ndarray, np.ndarray] | None = None

    def flows(self, frames: np.ndarray):
        key = id(frames)
        if self._cache is None or self._cache[0] != key:
            self._cache = (key, *pairwise_flows(frames, self.config.preset, self.config.verbose))
        return self._cache[1], self._cache[2]

    def _propagate(self, p0, t0, direction, flows_a, flows_b, T, H, W, tracks, vis, sel):
        c = self.config
        p = p0.copy()
        v = np.zeros_like(p)
        gap = np.zeros(len(p), int)
        lost = np.zeros(len(p), bool)
        t = t0
        while 0 <= t + direction < T:
            k = t if direction == 1 else t - 1  # index of the flow between t and t + direction
            fa = sample_flow(flows_a[k], p)
            q = p + fa
            err = np.linalg.norm(fa + sample_flow(flows_b[k], q), axis=1)
            ok = err < c.fb_abs_px + c.fb_rel * np.linalg.norm(fa, axis=1)
            # after a gap, the flow must also agree with the velocity carried through it
            ok &= (gap == 0) | (np.linalg.norm(fa - v, axis=1) < c.fb_abs_px + 0.25 * np.linalg.norm(v, axis=1))
            ok &= ~lost
            step = np.where(ok[:, None], fa, v)
            v = np.where(ok[:, None], fa, v)
            p = p + step
            inside = (p[:, 0] >= -0.5) & (p[:, 0] < W - 0.5) & (p[:, 1] >= -0.5) & (p[:, 1] < H - 0.5)
            gap = np.where(ok, 0, gap + 1)
            lost |= (gap > c.max_gap) | ~inside
            t += direction
            tracks[sel, t] = p
            vis[sel, t] = ok & inside & ~lost

    def track(self, frames: np.ndarray, queries: np.ndarray) -> TrackResult:
        T, H, W = frames.shape[:3]
        fwd, bwd = self.flows(frames)
        N = queries.shape[0]
        tracks = np.zeros((N, T, 2), np.float32)
        vis = np.zeros((N, T), bool)
        qt = queries[:, 0].round().astype(int)
        for t0 in np.unique(qt):
            sel = np.flatnonzero(qt == t0)
            p0 = queries[sel, 1:3].astype(np.float32)
            tracks[sel, t0] = p0
            vis[sel, t0] = True
            self._propagate(p0, t0, 1, fwd, bwd, T, H, W, tracks, vis, sel)
            self._propagate(p0, t0, -1, bwd, fwd, T, H, W, tracks, vis, sel)
        # where a point is not observed (occluded, lost, outside the image) its position is the
        # constant-velocity extrapolation from its last observed step
        return TrackResult(tracks, vis, vis.astype(np.float32), queries.astype(np.float32))


def grid_queries(t: int, H: int, W: int, stride: int, mask: np.ndarray | None = None) -> np.ndarray:
    """Queries ``[M,3]`` (t, x, y) on a regular grid of ``stride`` px, optionally where ``mask`` is set."""
    off = (stride - 1) / 2.0
    ys, xs = np.mgrid[off:H:stride, off:W:stride]
    xs, ys = xs.ravel(), ys.ravel()
    if mask is not None:
        keep = mask[ys.round().astype(int).clip(0, H - 1), xs.round().astype(int).clip(0, W - 1)]
        xs, ys = xs[keep], ys[keep]
    return np.stack([np.full(xs.shape, t, np.float64), xs, ys], 1)
