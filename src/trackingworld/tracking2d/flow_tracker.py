"""A weight-free tracker: OpenCV DIS optical flow between consecutive frames, chained over time in both
directions from each query frame, with forward-backward consistency as the occlusion test."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from trackingworld.progress import Progress
from trackingworld.tracking2d.base import TrackResult, hold_invisible


@dataclass
class FlowTrackerConfig:
    preset: str = "medium"  # DIS preset: ultrafast | fast | medium
    fb_abs_px: float = 1.0  # forward-backward error allowed: abs + rel * |flow|
    fb_rel: float = 0.05
    verbose: bool = False


def _dis(preset: str):
    p = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
         "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}[preset]
    return cv2.DISOpticalFlow_create(p)


def pairwise_flows(frames: np.ndarray, preset: str = "medium", verbose: bool = False):
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


def sample_flow(flow: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Bilinear sample of ``flow [H,W,2]`` at ``pts [M,2]`` (border replicated)."""
    m = pts.astype(np.float32).reshape(-1, 1, 2)
    out = cv2.remap(flow, m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1, 2)


class FlowTracker:
    """Chained optical flow with occlusion detection. Tracks are lost at the first occlusion or when they
    leave the image (a basic tracker: the positions are held afterwards and marked not visible)."""

    def __init__(self, config: FlowTrackerConfig | None = None):
        self.config = config or FlowTrackerConfig()
        self._cache: tuple[int, np.ndarray, np.ndarray] | None = None

    def flows(self, frames: np.ndarray):
        key = id(frames)
        if self._cache is None or self._cache[0] != key:
            self._cache = (key, *pairwise_flows(frames, self.config.preset, self.config.verbose))
        return self._cache[1], self._cache[2]

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
            for direction, flows_a, flows_b in ((1, fwd, bwd), (-1, bwd, fwd)):
                p = p0.copy()
                alive = np.ones(len(sel), bool)
                t = t0
                while 0 <= t + direction < T:
                    k = t if direction == 1 else t - 1  # index of the flow between t and t+direction
                    fa = sample_flow(flows_a[k], p)
                    q = p + fa
                    back = sample_flow(flows_b[k], q)
                    err = np.linalg.norm(fa + back, axis=1)
                    ok = err < self.config.fb_abs_px + self.config.fb_rel * np.linalg.norm(fa, axis=1)
                    inside = (q[:, 0] >= -0.5) & (q[:, 0] < W - 0.5) & (q[:, 1] >= -0.5) & (q[:, 1] < H - 0.5)
                    alive &= ok & inside
                    p = np.where(alive[:, None], q, p)
                    t += direction
                    tracks[sel, t] = p
                    vis[sel, t] = alive
        tracks = hold_invisible(tracks, vis)
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
