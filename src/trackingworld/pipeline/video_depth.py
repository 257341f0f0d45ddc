"""The appendix's consistent video depth: the raw prior's maps times a per-pixel scale ratio propagated from the
tracks' visible observations (``optim.densify.ratio_maps``), and the part of it that needs only the 2D tracks done
ahead of time on the second core while the rigid-mover step runs (:class:`SearchAhead`).

Conventions: ``uv [N,T,2]`` px, ``vis [N,T]``, world positions ``[N,T,3]`` metres, poses camera-to-world
``[T,4,4]``, the prior ``[T,h,w]`` metres."""

from __future__ import annotations

import threading

import numpy as np

from trackingworld.optim.densify import pixel_grid, pixel_neighbours, ratio_maps, thinned_observations
from trackingworld.optim.parallel import FramesAhead, core_taken
from trackingworld.pipeline.fields import REFERENCE_CELL_PX, observation_ratios
from trackingworld.pipeline.lift import sample_observations

K_NEAREST = 4  # references per pixel
# the most memory the neighbours searched ahead may hold (int32, k = 4: 6.6 MB a frame of 854x480 pixels, so 77
# frames; the frames past it are searched when the video depth is made, as without the search ahead)
AHEAD_BYTES = 512 * 2**20


class SearchAhead:
    """The video depth's work that reads only the 2D tracks ``uv [N,T,2]`` / ``vis [N,T]`` (which nothing changes
    from the rigid-mover step on): the thinned reference observations, then frame by frame the kNN search of every
    pixel of ``shape (h, w)`` among them, on a spare thread (:meth:`job` hands it :meth:`run`, one core's work).
    :func:`video_depth` takes what is done and does the rest as it would have; the numbers are the same either
    way."""

    def __init__(self, uv: np.ndarray, vis: np.ndarray, shape: tuple[int, int], budget_bytes: int = AHEAD_BYTES):
        self._uv, self._vis, self._shape = uv, vis, shape
        self._refs: tuple[np.ndarray, np.ndarray] | None = None
        self._pixels: np.ndarray | None = None  # [h*w,2] the pixels searched for, made once by the thread
        self._lock = threading.Lock()
        per_frame = shape[0] * shape[1] * K_NEAREST * 4
        self.frames = FramesAhead(self._search, range(min(vis.shape[1], budget_bytes // max(per_frame, 1))))
        self._idle = threading.Event()  # no run() going, nor one handed to a thread (job)
        self._idle.set()

    def references(self) -> tuple[np.ndarray, np.ndarray]:
        """(track [R], frame [R]): the visible observations thinned to one per ``REFERENCE_CELL_PX`` square of each
        frame, in frame order (``optim.densify.thinned_observations``), made once (waited for where in hand)."""
        with self._lock:
            if self._refs is None:
                self._refs = thinned_observations(self._uv, self._vis, REFERENCE_CELL_PX)
            return self._refs

    def _search(self, t: int) -> np.ndarray | None:
        n, f = self.references()
        rows = slice(*np.searchsorted(f, [t, t + 1]))
        return pixel_neighbours(self._uv[n[rows], t], self._pixels, K_NEAREST, workers=1)

    def run(self) -> None:
        """The references, then the frames' searches in order, until :meth:`finish` or the memory budget's last frame,
        with one core counted as taken (``optim.parallel.core_taken``: the work beside it splits among the others)."""
        try:
            with core_taken():
                self.references()
                self._pixels = pixel_grid(*self._shape)
                self.frames.run()
        finally:
            self._idle.set()

    def job(self):
        """:meth:`run`, to be handed to a thread now: :meth:`finish` then waits for it."""
        self._idle.clear()
        return self.run

    def finish(self) -> None:
        """No more frames searched ahead; returns once the frame in hand is finished and the core given back."""
        self.frames.stop()
        self._idle.wait()


def video_depth(uv: np.ndarray, vis: np.ndarray, xyz: np.ndarray, poses: np.ndarray, prior: np.ndarray,
                K: np.ndarray, ahead: SearchAhead | None = None) -> tuple[np.ndarray, int]:
    """The consistent video depth ``[T,h,w]`` float32 metres: each pixel's raw prior (``prior [T,h,w]``) times the
    ratio ``z / prior`` (``z`` the camera depth of the world positions ``xyz``, the prior read at the track) of its
    :data:`K_NEAREST` nearest thinned reference observations, inverse-distance weighted. The prior is sampled at
    those references only, not at every observation (``pipeline.lift.sample_observations``). ``ahead``: the part
    searched ahead (:class:`SearchAhead`; finished here). Returns the maps and the frames whose search was done
    ahead."""
    if ahead is not None:  # its core back first: the frames it did not reach run on every core
        ahead.finish()
        n, t = ahead.references()
    else:
        n, t = thinned_observations(uv, vis, REFERENCE_CELL_PX)
    d = sample_observations(prior, uv, n, t)
    ratio = observation_ratios(xyz, poses, n, t, d)
    neighbours = None if ahead is None else ahead.frames.take
    depth = ratio_maps(t, uv[n, t], d, ratio, prior.astype(np.float64), K, K_NEAREST, neighbours=neighbours) * prior
    return depth, 0 if ahead is None else ahead.frames.done
