"""Movers the masks missed whose image motion a static point explains: the depth-discrepancy test.

Stage 2 calls a background track a mover when no static point reprojects onto it (its offsets reach epsilon).
An object sliding along the epipolar lines of the camera's motion fails that test: a static point at another
depth traces the same pixels, and the bundle adjustment places it there. Only the depth prior tells: the
fitted point is then consistently nearer or farther than the prior says, on every track of the object, in
every frame.

The test, per visible observation of each static track (the pipeline passes at most about 16 of each track's
frames, spread over its span): the discrepancy ``e = log(z / D) - f_t(uv)`` between
the camera depth ``z`` of its fitted point and the prior ``D``, less the frame's smooth correction field of the
static tracks (``optim.ratio_field``: the prior's own scale and warp), taken to the nearest of the prior's value
at the pixel and its extremes within a pixel (:func:`blur_tolerant`: the prior's blur at depth edges). One
observation is noisy (the prior's noise), so the decision is a local majority: per frame, the fraction of
observations over ``e >= thresh`` (or ``<= -thresh``) in a window of ``window_px`` around each one, and a track is
a mover when more than half of its frames have a majority in the same direction. A median filter of scattered samples
is what this is; per frame it is counts on a grid of cells and two box filters (OpenCV), so the cost stays
linear in the observations.

Not in the paper (its depth term, in metres, switches the offsets on only beyond 2.5 m of disagreement, see
``stage2``); ``depth_mover_log = 0`` turns it off.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from trackingworld.geometry import invert_pose, nearest_pixel


def local_majority(frame: np.ndarray, uv: np.ndarray, flag: np.ndarray, n_frames: int, shape: tuple[int, int],
                   window_px: float, cell_px: float = 4.0) -> np.ndarray:
    """[M] float: for each observation (``frame [M]`` int, ``uv [M,2]`` px, ``flag [M]`` bool) the fraction of
    flagged observations of its frame within a ``window_px`` square around its ``cell_px`` grid cell."""
    return _window_fractions(frame, uv, [flag], n_frames, shape, window_px, cell_px)[0]


def _cells(frame, uv, n_frames: int, shape: tuple[int, int], window_px: float, cell_px: float):
    """The grid of the local majorities: (gh, gw, each observation's cell ``[M]`` = (frame x gh + y) x gw + x,
    the number of cells ``n_frames gh gw``, the window's side in cells, odd)."""
    h, w = shape
    gw, gh = int(np.ceil(w / cell_px)), int(np.ceil(h / cell_px))
    cx = np.clip((uv[:, 0] / cell_px).astype(np.int64), 0, gw - 1)
    cy = np.clip((uv[:, 1] / cell_px).astype(np.int64), 0, gh - 1)
    cell = (frame.astype(np.int64) * gh + cy) * gw + cx
    return gh, gw, cell, n_frames * gh * gw, max(int(round(window_px / cell_px)) | 1, 1)


def _window_fractions(frame, uv, flags: list, n_frames: int, shape: tuple[int, int], window_px: float,
                      cell_px: float = 4.0) -> list:
    """:func:`local_majority` of each of ``flags`` (``[M]`` bool each), the cells and the windows' counts of
    observations made once for all of them."""
    gh, gw, idx, size, k = _cells(frame, uv, n_frames, shape, window_px, cell_px)

    def window_sums(weights):  # per observation: the box sum (unnormalised) of weights over its window
        grid = np.bincount(idx, weights=weights, minlength=size).reshape(n_frames, gh, gw)
        out = np.stack([cv2.boxFilter(g, -1, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT)
                        for g in grid])
        return out.reshape(-1)[idx]

    counts = window_sums(None)  # each observation's window holds at least itself
    return [window_sums(f.astype(np.float64)) / counts for f in flags]


@dataclass(frozen=True)
class BilateralWindows:
    """The windows of :func:`_window_fractions` over a grid of (cell, depth bin) per frame: each observation's
    window is the ``window_px`` square of cells in its depth bin and the two beside it (a bilateral grid). A small
    mover in front of the background fills little of a square window, but most of the window of its own depth.
    The grid is kept sparse (its occupied entries sorted by frame, cell and bin; :func:`_sparse_grid`,
    :func:`_bilateral_fractions`, compiled), so the cost follows the observations, not the frames' area times the
    range of depths; built once for the observations of a test, it serves each round's flags."""

    inverse: np.ndarray  # [M] each observation's entry
    key_cell: np.ndarray  # [K] (frame x gh + y) x gw + x of each entry, ascending
    key_bin: np.ndarray  # [K] depth bin of each entry
    start: np.ndarray  # [T gh gw + 1] each cell's first entry
    grid: tuple[int, int, int]  # gh, gw, the window's reach in cells

    @classmethod
    def build(cls, frame, uv, log_depth, n_frames: int, shape: tuple[int, int], window_px: float,
              depth_bin: float, cell_px: float = 4.0) -> BilateralWindows:
        """The windows of the observations ``frame [M]``, ``uv [M,2]`` px with the prior's ``log_depth [M]``,
        depth bins ``depth_bin`` wide (log units)."""
        gh, gw, cell, size, k = _cells(frame, uv, n_frames, shape, window_px, cell_px)
        b = np.floor(log_depth / depth_bin).astype(np.int64)
        b -= b.min(initial=0)
        inverse, key_cell, key_bin, start = _sparse_grid(cell, b, size)
        return cls(inverse, key_cell, key_bin, start, (gh, gw, k // 2))

    def fractions(self, flags: list) -> list:
        """For each of ``flags`` ([M] bool each): [M] float, the fraction of each observation's window flagged."""
        if not len(flags):
            return []
        out = _bilateral_fractions(self.inverse, np.stack(flags), self.start, self.key_cell, self.key_bin,
                                   *self.grid)
        return list(out)


@njit(cache=True, nogil=True)
def _sparse_grid(cell, b, n_cells):
    """The occupied entries of a grid of (cell, bin) from observations in cells ``cell [M]`` (< ``n_cells``) and
    bins ``b [M]`` (>= 0): (inverse [M] each observation's entry, key_cell [K], key_bin [K] ascending by both,
    start [n_cells + 1] each cell's first entry). A counting sort by cell, then the few bins of each cell."""
    M = len(cell)
    per_cell = np.zeros(n_cells + 1, np.int64)
    for m in range(M):
        per_cell[cell[m] + 1] += 1
    for c in range(n_cells):
        per_cell[c + 1] += per_cell[c]
    order = np.empty(M, np.int64)
    fill = per_cell[:-1].copy()
    for m in range(M):
        order[fill[cell[m]]] = m
        fill[cell[m]] += 1
    inverse = np.empty(M, np.int64)
    key_cell = np.empty(M, np.int64)
    key_bin = np.empty(M, np.int64)
    start = np.zeros(n_cells + 1, np.int64)
    K = 0
    for c in range(n_cells):
        start[c] = K
        lo, hi = per_cell[c], per_cell[c + 1]
        if hi == lo:
            continue
        bins = np.sort(b[order[lo:hi]])
        first = K
        for i in range(len(bins)):
            if i == 0 or bins[i] != bins[i - 1]:
                key_cell[K] = c
                key_bin[K] = bins[i]
                K += 1
        for i in range(lo, hi):  # the cell's entries are few: a linear search
            m = order[i]
            k = first
            while key_bin[k] != b[m]:
                k += 1
            inverse[m] = k
    start[n_cells] = K
    return inverse, key_cell[:K].copy(), key_bin[:K].copy(), start


@njit(cache=True, nogil=True)
def _bilateral_fractions(inverse, flags, start, key_cell, key_bin, gh, gw, r):
    """[F,M]: for each observation (its entry ``inverse [M]`` of the sparse grid of :func:`_sparse_grid`) the
    fraction of the observations in its window flagged by each of ``flags [F,M]`` (bool): those of the entries of
    the cells within ``r`` of its own (``key_cell`` = (frame x gh + y) x gw + x), in its bin or the two beside."""
    F, M = flags.shape
    K = len(key_bin)
    own = np.zeros((K, F + 1))  # per entry: observations, flagged ones
    for m in range(M):
        k = inverse[m]
        own[k, 0] += 1.0
        for f in range(F):
            if flags[f, m]:
                own[k, f + 1] += 1.0
    near = np.zeros((K, F + 1))
    area = gh * gw
    for i in range(K):
        fr = key_cell[i] // area
        y = (key_cell[i] % area) // gw
        x = key_cell[i] % gw
        for yy in range(max(0, y - r), min(gh, y + r + 1)):
            for xx in range(max(0, x - r), min(gw, x + r + 1)):
                c = fr * area + yy * gw + xx
                for j in range(start[c], start[c + 1]):
                    if abs(key_bin[j] - key_bin[i]) <= 1:
                        for ch in range(F + 1):
                            near[i, ch] += own[j, ch]
    out = np.empty((F, M))
    for m in range(M):
        k = inverse[m]
        for f in range(F):
            out[f, m] = near[k, f + 1] / near[k, 0]
    return out


def depth_movers(track: np.ndarray, frame: np.ndarray, uv: np.ndarray, e: np.ndarray, n_tracks: int,
                 n_frames: int, shape: tuple[int, int], thresh: float = 0.05, window_px: float = 20.0) -> np.ndarray:
    """[n_tracks] bool: the tracks whose static point disagrees with the prior, region by region.

    The visible observations of the tracks tested: ``track [M]`` and ``frame [M]`` indices, pixels ``uv [M,2]``
    (x right, y down) and the log discrepancy ``e [M]`` (fitted camera depth over the prior, the frame's field
    removed). ``thresh``: log units (0.05 = 5%); ``window_px``: side of the neighbourhood's square (pixels of the
    image ``shape`` (h, w)). A track with no observation is never flagged."""
    return depth_movers_at(track, frame, uv, e, n_tracks, n_frames, shape, [thresh], window_px)[0]


def depth_movers_at(track: np.ndarray, frame: np.ndarray, uv: np.ndarray, e: np.ndarray, n_tracks: int,
                    n_frames: int, shape: tuple[int, int], thresholds, window_px: float = 20.0,
                    windows: BilateralWindows | None = None, windows_factor: float = 0.0) -> list:
    """:func:`depth_movers` at each of ``thresholds`` (log units): one [n_tracks] bool per threshold, the cells
    and the windows' counts of observations made once for all of them; with ``windows`` (built for these
    observations) the local majority is over those (:class:`BilateralWindows`) instead of ``window_px`` squares."""
    out = [np.zeros(n_tracks, bool) for _ in thresholds]
    if not len(track):
        return out
    n_obs = np.bincount(track, minlength=n_tracks)
    flags = [f for th in thresholds for f in (e >= th, e <= -th)]
    if windows is not None and windows_factor <= 0:
        wins = [f > 0.5 for f in windows.fractions(flags)]
    else:
        wins = [f > 0.5 for f in _window_fractions(frame, uv, flags, n_frames, shape, window_px)]
        if windows is not None:
            more = [f for th in thresholds for f in (e >= th * windows_factor, e <= -th * windows_factor)]
            wins = [a | (f > 0.5) for a, f in zip(wins, windows.fractions(more), strict=True)]
    for i, win in enumerate(wins):
        won = np.bincount(track, weights=win.astype(np.float64), minlength=n_tracks)
        out[i // 2] |= won * 2 > n_obs
    return out


def prior_spread(t: np.ndarray, uv: np.ndarray, prior: np.ndarray, radius: int) -> tuple[np.ndarray, np.ndarray]:
    """The range of the prior around observations in frames ``t [M]`` (ascending) at pixels ``uv [M,2]``: (far,
    near), each [M] log units, the log of the farthest / nearest value of the prior ``[T,H,W]`` metres within
    ``radius`` px (a square) over its value at the pixel (far >= 0 >= near). Per frame, a grey dilation and
    erosion of the log prior (OpenCV)."""
    _, h, w = prior.shape
    x, y = nearest_pixel(uv, w, h)
    kernel = np.ones((2 * radius + 1,) * 2, np.uint8)
    far, near = np.zeros(len(t)), np.zeros(len(t))
    bounds = np.searchsorted(t, np.arange(len(prior) + 1))
    for f in np.flatnonzero(np.diff(bounds)):
        s = slice(bounds[f], bounds[f + 1])
        log_d = np.log(np.maximum(prior[f], 1e-6, dtype=np.float32))
        at = log_d[y[s], x[s]]
        far[s] = cv2.dilate(log_d, kernel)[y[s], x[s]] - at
        near[s] = cv2.erode(log_d, kernel)[y[s], x[s]] - at
    return far, near


def blur_tolerant(e: np.ndarray, far: np.ndarray, near: np.ndarray) -> np.ndarray:
    """[M] log units: the discrepancies ``e [M]`` (fitted over prior) measured to whichever is nearest of the
    prior's value at the pixel and its farthest and nearest values within reach (``far``, ``near`` [M],
    :func:`prior_spread`). A monocular prior blurs across depth edges: a static point beside one reads a mix of
    both sides at its pixel, while its own side's depth lies a pixel or two away, at one end of that range. A
    fit that lies between the two sides is not forgiven: at a mover's rim, the background's depth within reach
    would otherwise excuse a point the bundle adjustment placed too far (a range-as-interval rule did so, see
    ``docs/lifting.md`` item 5). Compiled for float64 (:func:`_nearest_end`, numpy's numbers to the bit: 3M
    observations 0.40 -> 0.01 s); :func:`blur_tolerant_numpy` is the reference."""
    if e.dtype == far.dtype == near.dtype == np.float64:
        return _nearest_end(e, far, near)
    return blur_tolerant_numpy(e, far, near)


def blur_tolerant_numpy(e: np.ndarray, far: np.ndarray, near: np.ndarray) -> np.ndarray:
    """:func:`blur_tolerant` in numpy (the reference of :func:`_nearest_end`)."""
    ends = np.stack([np.zeros_like(e), far, near])
    nearest = np.argmin(np.abs(e[None] - ends), axis=0)
    return e - ends[nearest, np.arange(len(e))]


@njit(cache=True, nogil=True)
def _nearest_end(e, far, near):
    """:func:`blur_tolerant_numpy` in one pass: ``e - c`` for the first of (0, far, near) nearest ``e``, where
    numpy's ``argmin`` takes the first NaN of the distances if there is one."""
    out = np.empty(len(e))
    for m in range(len(e)):
        x = e[m]
        best = 0.0
        d = abs(x)
        for c in (far[m], near[m]):
            dc = abs(x - c)
            if dc < d or (dc != dc and d == d):
                best, d = c, dc
        out[m] = x - best
    return out


def log_depth_ratios(tracks, obs, xyz, D, poses) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The observations ``obs [n,T]`` (bool) of ``tracks`` [n] (indices) in frame order and the log ratio of the
    camera depth of their world position to the prior: (position in ``tracks`` [M], frame [M], log(z / D) [M])."""
    k, t = np.nonzero(np.ascontiguousarray(obs.T))[::-1]  # frame-major
    n = tracks[k]
    w2c = invert_pose(poses)
    z = np.einsum("mj,mj->m", w2c[t, 2, :3], xyz[n, t]) + w2c[t, 2, 3]
    return k, t, np.log(np.maximum(z, 1e-6) / np.maximum(D[n, t], 1e-6))


def less_fields(uv_obs, t, e, fields) -> tuple[np.ndarray, np.ndarray]:
    """Observations (pixels ``uv_obs [M,2]``, frame ``t [M]`` ascending, log ratio ``e [M]``) less their frame's
    field (``fields``: per frame a callable of pixels, ``pipeline.fields.static_fields``, or None): (kept [M]
    bool: the frame has a field, e - field at the kept ones)."""
    bounds = np.searchsorted(t, np.arange(len(fields) + 1))
    keep = np.ones(len(t), bool)
    out = e.copy()
    for tt, f in enumerate(fields):
        s = slice(bounds[tt], bounds[tt + 1])
        if f is None:
            keep[s] = False
        elif bounds[tt] < bounds[tt + 1]:
            out[s] -= f(uv_obs[s])
    return keep, out[keep]
