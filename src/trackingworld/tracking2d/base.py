"""Tracker interface (kept small, like CoTracker's predictor): frames + queries in, tracks out."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass
class TrackResult:
    """2D tracks of N query points over T frames.

    tracks: [N,T,2] float32 pixels (x right, y down, pixel centres at integers); finite everywhere. Where
        the point is not visible: the tracker's estimate (carried through occlusion), or, for trackers and
        files without one, the last observed position (:func:`hold_invisible`).
    visible: [N,T] bool. confidence: [N,T] in [0,1], float32 from a tracker, float16 as cached or read from a
        tracks file (the lifting does not read it). queries: [N,3] float32 (t, x, y).
    """

    tracks: np.ndarray
    visible: np.ndarray
    confidence: np.ndarray
    queries: np.ndarray

    def __post_init__(self) -> None:
        N = self.queries.shape[0]
        T = self.visible.shape[1] if self.visible.ndim == 2 else 0
        assert self.tracks.shape == (N, T, 2), self.tracks.shape
        assert self.visible.shape == self.confidence.shape == (N, T)

    @staticmethod
    def concatenate(parts: list[TrackResult]) -> TrackResult:
        return TrackResult(*(np.concatenate([getattr(p, k) for p in parts]) for k in
                             ("tracks", "visible", "confidence", "queries")))


class Tracker(Protocol):
    def track(self, frames: np.ndarray, queries: np.ndarray) -> TrackResult:
        """frames [T,H,W,3] uint8 RGB, queries [N,3] (t, x, y) -> tracks in both directions of time."""
        ...


def hold_invisible(values: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """Fill the frames where a track is not visible with its value at the nearest visible frame in time
    (ties go to the earlier frame). values [N,T,C], visible [N,T]; tracks never visible are left as is."""
    return np.take_along_axis(values, nearest_visible_frame(visible)[..., None], axis=1)


def nearest_visible_frame(visible: np.ndarray) -> np.ndarray:
    """``[N,T]`` int32: for every (track, frame) the nearest frame in time where the track is visible (ties go
    to the earlier frame; the frame itself where it is visible, or where the track is never visible)."""
    N, T = visible.shape
    vis = np.ascontiguousarray(visible.T)  # [T,N]: the scans below run along axis 0, vectorised over tracks
    idx = np.arange(T, dtype=np.int32)[:, None]
    prev = np.where(vis, idx, np.int32(-1))
    np.maximum.accumulate(prev, axis=0, out=prev)
    nxt = np.where(vis, idx, np.int32(T))[::-1]
    nxt = np.minimum.accumulate(nxt, axis=0)[::-1]
    use_next = (prev < 0) | ((nxt < T) & (nxt - idx < idx - prev))
    src = np.where(use_next, nxt, prev)
    src = np.where((src < 0) | (src >= T), idx, src)
    return np.ascontiguousarray(src.T)
