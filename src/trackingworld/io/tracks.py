"""Reading 2D tracks computed elsewhere (``--tracks FILE``).

Accepted ``.npz`` / ``.npy`` (dict) layouts, recognised by their keys:

* this package's (``trackingworld track2d``): ``tracks [N,T,2]``, ``visible [N,T]`` bool, ``queries [N,3]`` as
  (t, x, y), optional ``confidence [N,T]`` (not read);
* CoTracker: ``tracks [T,N,2]`` (or ``[1,T,N,2]``), ``visibility [T,N]`` (bool or probability),
  ``queries [N,3]`` as (t, x, y);
* TAPNet / TAP-Vid: ``tracks [N,T,2]``, ``occluded [N,T]`` bool, optional ``query_points [N,3]`` as (t, y, x);
* DELTA-style dense dumps saved as ``coords [T,N,2]`` + ``vis [T,N]`` (+ ``queries``) are read like CoTracker.

Pixels are x right / y down at the video's resolution. Without queries, a track's query frame is its first
visible frame.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from trackingworld.errors import InputError
from trackingworld.io.arrays import read_arrays
from trackingworld.tracking2d.base import TrackResult, hold_invisible

# a tracks file's visible points may lie outside the frames (a tracker's points at the border): by at most this
# share of the frames' side, for all but OUTSIDE_SHARE of them, before the file is taken for another resolution's
OUTSIDE_MARGIN = 0.1
OUTSIDE_SHARE = 0.01
CHECK_ROWS = 65536  # tracks checked at a time


def load_tracks(path: str | os.PathLike | None, T: int, size: tuple[int, int] | None = None) -> TrackResult:
    """A tracks file (``trackingworld track2d``'s, CoTracker's, TAPNet's) for a video of ``T`` frames of ``size``
    (W, H) px (None: not checked): InputError where it does not fit them, one line naming the file. A file of
    ``track2d`` records its frames' size and must match it; another tracker's must keep its visible points on the
    frames (:data:`OUTSIDE_MARGIN`, :data:`OUTSIDE_SHARE`)."""
    if path is None:
        raise InputError("--tracker file needs --tracks FILE")
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such tracks file")
    d = read_arrays(path, "tracks")
    d.pop("", None)  # a bare .npy array: no layout to read it by (the error below)
    if "visible" in d and "tracks" in d:  # trackingworld track2d
        tracks, vis, queries = d["tracks"], d["visible"], d.get("queries")
    elif "occluded" in d:  # TAPNet
        tracks, vis = d["tracks"], ~d["occluded"].astype(bool)
        q = d.get("query_points")
        queries = None if q is None else np.stack([q[:, 0], q[:, 2], q[:, 1]], 1)
    elif "tracks" in d or "coords" in d:  # CoTracker / DELTA
        tracks = np.squeeze(d.get("tracks", d.get("coords")))
        vis = np.squeeze(d.get("visibility", d.get("vis", np.ones(tracks.shape[:2]))))
        if vis.dtype != bool:
            vis = vis > 0.5
        tracks, vis = np.swapaxes(tracks, 0, 1), vis.T
        queries = d.get("queries")
        queries = None if queries is None else np.squeeze(queries)
    else:
        raise InputError(f"{path}: unknown tracks layout (keys: {', '.join(d) or 'none'}); "
                         "expected trackingworld track2d's (tracks, visible, queries), CoTracker (tracks, visibility, "
                         "queries) or TAPNet (tracks, occluded)")
    if tracks.ndim != 3 or tracks.shape[-1] != 2 or vis.shape != tracks.shape[:2]:
        raise InputError(f"{path}: tracks {tracks.shape} and visibility {vis.shape} do not match")
    if tracks.shape[1] != T:
        raise InputError(f"{path}: tracks cover {tracks.shape[1]} frames, the video has {T}")
    if size is not None:
        _check_size(path, d.get("size"), tracks, vis, size)
    if queries is None:
        t0 = np.where(vis.any(1), vis.argmax(1), 0)
        queries = np.concatenate([t0[:, None], tracks[np.arange(len(t0)), t0]], 1)
    tracks = np.nan_to_num(np.asarray(tracks, np.float32), copy=False)  # the file's own array: no copy to spare
    vis = vis.astype(bool)
    tracks = hold_invisible(tracks, vis)
    return TrackResult(tracks, vis, vis.astype(np.float16), queries.astype(np.float32))  # confidence: not read


def _check_size(path, made_on, tracks: np.ndarray, vis: np.ndarray, size: tuple[int, int]) -> None:
    """InputError where the tracks ``[N,T,2]`` (seen where ``vis [N,T]``) belong to frames of another size than
    ``size`` (W, H): ``made_on`` the (W, H) the file records (track2d's), else the extent of its visible points."""
    W, H = size
    if made_on is not None:
        w, h = (int(v) for v in np.asarray(made_on).reshape(-1)[:2])
        if (w, h) != (W, H):
            raise InputError(f"{path}: the tracks were made on {w}x{h} frames, this video's are {W}x{H}")
        return
    mx, my = OUTSIDE_MARGIN * W, OUTSIDE_MARGIN * H
    n_seen = n_out = 0
    for a in range(0, len(tracks), CHECK_ROWS):  # by rows: the visible points of a long video's file are gigabytes
        seen = tracks[a:a + CHECK_ROWS][vis[a:a + CHECK_ROWS]]
        n_seen += len(seen)
        n_out += int(((seen[:, 0] < -mx) | (seen[:, 0] > W - 1 + mx) | (seen[:, 1] < -my)
                      | (seen[:, 1] > H - 1 + my)).sum())
    if n_out > OUTSIDE_SHARE * n_seen:
        rows = slice(None, None, max(1, len(tracks) // CHECK_ROWS))  # the message's percentile from a sample of rows
        x1, y1 = np.percentile(tracks[rows][vis[rows]], 99, axis=0)
        raise InputError(f"{path}: {100 * n_out / n_seen:.0f}% of the visible track points lie outside the {W}x{H} "
                         f"frames (99th percentile x {x1:.0f}, y {y1:.0f} px): tracks of another resolution?")
