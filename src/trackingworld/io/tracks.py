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


def load_tracks(path: str | os.PathLike | None, T: int) -> TrackResult:
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
    if queries is None:
        t0 = np.where(vis.any(1), vis.argmax(1), 0)
        queries = np.concatenate([t0[:, None], tracks[np.arange(len(t0)), t0]], 1)
    tracks = np.nan_to_num(np.asarray(tracks, np.float32), copy=False)  # the file's own array: no copy to spare
    vis = vis.astype(bool)
    tracks = hold_invisible(tracks, vis)
    return TrackResult(tracks, vis, vis.astype(np.float16), queries.astype(np.float32))  # confidence: not read
