"""Dense 2D tracks of almost all pixels of all frames (paper Sec. 3.2 and A.6).

For each query frame (every frame by default) the pixels that no existing visible track covers (within
``cover_radius`` px) are grouped into connected components; components smaller than ``min_component``
(tau = 50 px) are dropped; the rest become new tracks. New tracks come from a grid tracked at ``stride`` px
from that frame, in both directions of time, lifted to every pixel by the convex upsampler
(``mode='upsample'``), or from tracking every pixel directly (``mode='direct'``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from trackingworld.progress import Progress
from trackingworld.tracking2d.base import TrackResult
from trackingworld.tracking2d.upsample import UpsampleConfig, apply_weights, neighbour_weights


@dataclass
class DenseConfig:
    stride: int = 4  # s: grid stride of the sparse tracks
    query_stride: int = 1  # every frame is a query frame (the authors' code: 10)
    first_frame_only: bool = False  # the paper's "w/o T.E.F" ablation
    cover_radius: float = 1.0  # r: a pixel is covered when a visible track lies within r px
    min_component: int = 50  # tau: smallest uncovered component that becomes new tracks
    mode: str = "upsample"  # upsample | direct
    vis_threshold: float = 0.5
    motion_window: int = 3  # w: the upsampler's motion cue is each pixel's displacement to frames t +- w
    upsample: UpsampleConfig = field(default_factory=UpsampleConfig)
    device: str = "cpu"
    verbose: bool = True


def splat_coverage(covered: np.ndarray, tracks: np.ndarray, visible: np.ndarray, radius: float) -> None:
    """Mark in ``covered [T,H,W]`` every pixel within ``radius`` of a visible track position."""
    T, H, W = covered.shape
    if radius <= 0:  # the authors' rule: a pixel is covered when a visible track lands on it after rounding
        for t in range(T):
            xy = np.round(tracks[visible[:, t], t]).astype(np.int64)
            ok = (xy[:, 0] >= 0) & (xy[:, 0] < W) & (xy[:, 1] >= 0) & (xy[:, 1] < H)
            covered[t].reshape(-1)[xy[ok, 1] * W + xy[ok, 0]] = True
        return
    rr = int(np.ceil(radius))
    offs = [(dx, dy) for dx in range(-rr, rr + 1) for dy in range(-rr, rr + 1)]
    for t in range(T):
        p = tracks[visible[:, t], t]
        if not len(p):
            continue
        base = np.floor(p).astype(np.int64)
        flat = covered[t].reshape(-1)
        for dx, dy in offs:
            x, y = base[:, 0] + dx, base[:, 1] + dy
            ok = (x >= 0) & (x < W) & (y >= 0) & (y < H)
            ok &= ((x - p[:, 0]) ** 2 + (y - p[:, 1]) ** 2) <= radius**2 + 1e-9
            flat[y[ok] * W + x[ok]] = True


def new_track_pixels(uncovered: np.ndarray, min_component: int) -> np.ndarray:
    """Pixels ``[M,2]`` (x, y) of the uncovered connected components (8-connected) with >= min_component px."""
    n, lab, stats, _ = cv2.connectedComponentsWithStats(uncovered.astype(np.uint8), connectivity=8)
    keep = np.zeros(n, bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= min_component
    ys, xs = np.nonzero(keep[lab])
    return np.stack([xs, ys], 1).astype(np.float32)


class DenseTracker:
    """Dense tracking of every frame on top of a sparse tracker with the :class:`Tracker` interface.

    The sparse tracker must expose ``flows(frames)`` (forward / backward pairwise flow) for the motion cue of
    the upsampler; trackers without it get colour and space weights only.
    """

    def __init__(self, sparse, config: DenseConfig | None = None):
        self.sparse = sparse
        self.cfg = config or DenseConfig()
        self.stats: dict = {}

    def _motion_features(self, frames: np.ndarray, t: int) -> np.ndarray | None:
        """Motion of every pixel of frame ``t`` ``[H,W,4]``: its displacement (px) to frames t + w and t - w
        (w = ``motion_window``, fewer at the ends of the video) by chained optical flow, divided by sqrt(w)."""
        if not hasattr(self.sparse, "flows"):
            return None
        fwd, bwd = self.sparse.flows(frames)
        T = len(frames)
        H, W = frames.shape[1:3]
        w = self.cfg.motion_window
        base = np.stack(np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32)), -1)
        out = []
        for direction, flows in ((1, fwd), (-1, bwd)):
            p = base.copy()
            for tt in range(t, t + direction * w, direction):
                if not 0 <= tt + direction < T:
                    break
                k = tt if direction == 1 else tt - 1  # flow between tt and tt + direction
                p += cv2.remap(flows[k], p[..., 0], p[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            out.append(p - base)
        return np.concatenate(out, -1) / np.float32(np.sqrt(w))

    def _track_pixels(self, frames: np.ndarray, t: int, pix: np.ndarray):
        """Tracks [M,T,2] and visibility weight [M,T] for pixels ``pix`` of query frame ``t``."""
        cfg = self.cfg
        T, H, W = frames.shape[:3]
        if cfg.mode == "direct":
            q = np.concatenate([np.full((len(pix), 1), t, np.float32), pix], 1)
            r = self.sparse.track(frames, q)
            return r.tracks, r.visible.astype(np.float32)
        s = cfg.stride
        off = (s - 1) / 2.0
        gh, gw = len(np.arange(off, H, s)), len(np.arange(off, W, s))
        # only the grid nodes within the 5x5 neighbourhoods of the new pixels are tracked
        need = np.zeros((gh, gw), bool)
        cx = np.clip(np.round((pix[:, 0] - off) / s).astype(int), 0, gw - 1)
        cy = np.clip(np.round((pix[:, 1] - off) / s).astype(int), 0, gh - 1)
        need[cy, cx] = True
        k = 2 * cfg.upsample.radius + 1
        need = cv2.dilate(need.astype(np.uint8), np.ones((k, k), np.uint8)) > 0
        gy, gx = np.nonzero(need)
        q = np.stack([np.full(len(gx), t, np.float32), off + gx * s, off + gy * s], 1).astype(np.float32)
        r = self.sparse.track(frames, q)
        grid_tracks = np.zeros((gh * gw, T, 2), np.float32)
        grid_vis = np.zeros((gh * gw, T), bool)
        grid_tracks[gy * gw + gx] = r.tracks
        grid_vis[gy * gw + gx] = r.visible
        image = cv2.GaussianBlur(frames[t].astype(np.float32) / 255.0, (0, 0), 1.0)
        idx, w = neighbour_weights(pix, (gh, gw), s, image, self._motion_features(frames, t), need, cfg.upsample)
        return apply_weights(pix, idx, w, grid_tracks, grid_vis, t, cfg.device,
                             affine_ridge=cfg.upsample.affine_ridge)

    def track_all(self, frames: np.ndarray) -> TrackResult:
        """Dense tracks of almost all pixels of all frames."""
        cfg = self.cfg
        T, H, W = frames.shape[:3]
        covered = np.zeros((T, H, W), bool)
        parts: list[TrackResult] = []
        qframes = [0] if cfg.first_frame_only else list(range(0, T, cfg.query_stride))
        bar = Progress("track2d: query frame", len(qframes), cfg.verbose)
        t_start = time.perf_counter()
        n_new = []
        for i, t in enumerate(qframes):
            pix = new_track_pixels(~covered[t], cfg.min_component if t > 0 else 1)
            if len(pix):
                tr, vw = self._track_pixels(frames, t, pix)
                vis = vw >= cfg.vis_threshold
                inside = (tr[..., 0] >= -0.5) & (tr[..., 0] < W - 0.5) & (tr[..., 1] >= -0.5) & (tr[..., 1] < H - 0.5)
                vis &= inside
                vis[:, t] = True
                tr[:, t] = pix
                splat_coverage(covered, tr, vis, cfg.cover_radius)
                q = np.concatenate([np.full((len(pix), 1), t, np.float32), pix], 1)
                parts.append(TrackResult(tr, vis, np.clip(vw, 0, 1).astype(np.float32), q))
            n_new.append(len(pix))
            bar.update(i + 1, f"new tracks {len(pix)}, total {sum(n_new)}")
        self.stats = {"new_tracks_per_query_frame": n_new, "seconds": time.perf_counter() - t_start,
                      "coverage_per_frame": covered.reshape(T, -1).mean(1).tolist()}
        return TrackResult.concatenate(parts)
