"""A smooth field over one image fitted to scattered samples: the prior's local depth correction.

A monocular depth prior is off by more than one scale per frame: its error is a smooth multiplicative warp
over the image that drifts from frame to frame. The static tracks measure it where they are (the ratio of
their bundle-adjusted camera depth to the prior); stage 3 needs it where the moving objects are, which the
static tracks surround but do not cover. One median per frame misses the warp; the nearest static tracks
(``propagate_ratio``) follow the noise of a few samples and the blurred prior at the objects' borders.

This fits ``log(ratio)`` with a bilinear grid of ``(gx + 1) x (gy + 1)`` nodes spanning the image, a
first-difference smoothness penalty between neighbouring nodes (which also carries the field into the parts
of the image with no samples) and a Cauchy reweighting against outliers. The grid has tens of nodes, so the
normal equations are solved densely. scipy's ``RBFInterpolator`` / ``griddata`` interpolate, but they do not
smooth robustly with a bounded number of unknowns, which is why this is written here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial

import numpy as np
from numba import njit

from trackingworld.optim.parallel import in_parts, part_bounds, worker_threads


@dataclass(frozen=True)
class LogField:
    """A fitted field: ``values [(gy+1)*(gx+1)]`` at the grid nodes (row-major, y down), plus ``offset``."""

    values: np.ndarray
    offset: float
    shape: tuple[int, int]  # (h, w) pixels of the image the grid spans
    cells: tuple[int, int]  # (gx, gy) grid cells across and down

    def __call__(self, uv: np.ndarray) -> np.ndarray:
        """The field at pixels ``uv [Q,2]`` (x right, y down) -> ``[Q]`` (log units, like the samples)."""
        p = np.ascontiguousarray(np.asarray(uv).reshape(-1, 2), np.float64)  # float32 pixels are exact in float64
        return _field_at(p, np.ascontiguousarray(self.values, np.float64), float(self.offset), *self.shape,
                         *self.cells)

    def image(self) -> np.ndarray:
        """The field at every pixel, ``[h,w]`` float32 (log units): the same values as calling it at the integer
        pixels, from two small matrix products (the interpolation is separable), to be sampled at many points."""
        h, w = self.shape
        gx, gy = self.cells
        nodes = self.values.reshape(gy + 1, gx + 1)
        return (_axis_weights(h, gy) @ nodes @ _axis_weights(w, gx).T + self.offset).astype(np.float32)


def _axis_weights(n: int, g: int) -> np.ndarray:
    """``[n, g+1]``: the linear interpolation weights of the g + 1 nodes spanning n pixels, at each pixel."""
    x = np.clip(np.arange(n) / max(n - 1, 1) * g, 0.0, g - 1e-9)
    i = np.floor(x).astype(np.int64)
    out = np.zeros((n, g + 1))
    out[np.arange(n), i] = 1 - (x - i)
    out[np.arange(n), i + 1] = x - i
    return out


def _bilinear(uv: np.ndarray, shape: tuple[int, int], cells: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The four grid nodes around each pixel ``uv [Q,2]`` and their bilinear weights, both ``[Q,4]``."""
    h, w = shape
    gx, gy = cells
    p = np.asarray(uv, np.float64).reshape(-1, 2)  # float64: a float32 clip at gx - 1e-9 rounds up to gx
    x = np.clip(p[:, 0] / max(w - 1, 1) * gx, 0.0, gx - 1e-9)
    y = np.clip(p[:, 1] / max(h - 1, 1) * gy, 0.0, gy - 1e-9)
    i, j = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = x - i, y - j
    nx = gx + 1
    idx = np.stack([j * nx + i, j * nx + i + 1, (j + 1) * nx + i, (j + 1) * nx + i + 1], 1)
    wts = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], 1)
    return idx, wts


@njit(cache=True, error_model="numpy", inline="always")
def _cell(u, n, g):
    """A pixel coordinate ``u`` of an image ``n`` px across, on a grid of ``g`` cells: (its cell, the fraction
    into it), as :func:`_bilinear` computes them (in float64, clipped inside the last cell)."""
    x = min(max(u / max(n - 1, 1) * g, 0.0), g - 1e-9)
    i = math.floor(x)
    return int(i), x - i


@njit(cache=True, error_model="numpy", nogil=True)
def _field_at(uv, values, offset, h, w, gx, gy):
    """``[Q]``: the field of node ``values`` and ``offset`` at pixels ``uv [Q,2]``, :func:`_bilinear`'s weights
    summed in its order (the numpy code this replaced, to the bit)."""
    out = np.empty(len(uv))
    nx = gx + 1
    for q in range(len(uv)):
        i, fx = _cell(uv[q, 0], w, gx)
        j, fy = _cell(uv[q, 1], h, gy)
        k = j * nx + i
        f = values[k] * ((1 - fx) * (1 - fy))
        f += values[k + 1] * (fx * (1 - fy))
        f += values[k + nx] * ((1 - fx) * fy)
        f += values[k + nx + 1] * (fx * fy)
        out[q] = f + offset
    return out


def _difference_operator(cells: tuple[int, int], order: int = 1) -> np.ndarray:
    """``L^T L`` of the differences between neighbouring nodes: first differences horizontally and vertically
    (``order`` 1, a membrane: a hole between samples is filled flat), or the thin-plate energy of second
    differences, f_xx^2 + 2 f_xy^2 + f_yy^2 (``order`` 2: a hole continues the slopes around it; planes cost
    nothing)."""
    gx, gy = cells
    node = np.arange((gx + 1) * (gy + 1)).reshape(gy + 1, gx + 1)
    m = node.size
    if order == 1:
        stencils = [((node[:, :-1], -1.0), (node[:, 1:], 1.0)), ((node[:-1], -1.0), (node[1:], 1.0))]
    elif order == 2:
        r2 = np.sqrt(2.0)
        stencils = [((node[:, :-2], 1.0), (node[:, 1:-1], -2.0), (node[:, 2:], 1.0)),
                    ((node[:-2], 1.0), (node[1:-1], -2.0), (node[2:], 1.0)),
                    ((node[:-1, :-1], r2), (node[:-1, 1:], -r2), (node[1:, :-1], -r2), (node[1:, 1:], r2))]
    else:
        raise ValueError(f"order: {order} is not 1 or 2")
    rows = []
    for st in stencils:
        L = np.zeros((st[0][0].size, m))
        for nodes, c in st:
            L[np.arange(nodes.size), nodes.ravel()] += c
        rows.append(L)
    L = np.concatenate(rows)
    return L.T @ L


def fit_log_field(uv: np.ndarray, values: np.ndarray, shape: tuple[int, int], cells: tuple[int, int] = (8, 6),
                  smooth: float = 0.01, scale: float = 0.02, iters: int = 4) -> LogField:
    """Robust smooth field through samples ``values [R]`` (log units) at pixels ``uv [R,2]`` of an image of
    ``shape`` (h, w).

    ``smooth``: weight of the node differences per sample per node (independent of how many samples there
    are); ``scale``: the Cauchy scale of the residuals (0.02 = 2% in depth); ``iters``: reweighted solves.
    The field is fitted about the samples' median; nodes with no samples near them take their values from
    their neighbours through the smoothness penalty. No samples: a field of zeros. (:func:`fit_log_fields`
    of one frame.)
    """
    if len(values) == 0:
        return LogField(np.zeros((cells[0] + 1) * (cells[1] + 1)), 0.0, shape, cells)
    return fit_log_fields([(uv, values)], shape, cells, smooth, 0.0, scale, iters)[0]


def fit_log_fields(samples: list, shape: tuple[int, int], cells: tuple[int, int] = (8, 6), smooth: float = 0.01,
                   temporal: float = 0.0, scale: float = 0.02, iters: int = 4, order: int = 1) -> list:
    """Fields of a sequence of frames: ``samples`` per frame ``(uv [R,2], values [R])``, or None or no samples
    (None out). Each frame is :func:`fit_log_field`'s problem about its own median; ``temporal`` > 0 fits them
    together, with a penalty on the change of each frame's field shape from the previous frame's (node
    differences less their mean, so each frame keeps its own level: the prior's per-frame scale), weighted like
    ``smooth`` (per sample of the average frame per node). A node that no sample of its frame reaches then takes
    its value from the neighbouring frames, where it may be seen, before its spatial neighbours. The system is
    block tridiagonal in time and is solved exactly by block elimination (T solves of the nodes' size);
    ``temporal`` 0: each frame's block alone. ``order``: the smoothness penalty's (:func:`_difference_operator`).
    Each frame's normal equations and reweighting are compiled (:func:`_normal_blocks`, :func:`_reweight`), the
    frames shared among threads."""
    T = len(samples)
    m = (cells[0] + 1) * (cells[1] + 1)
    LtL = _difference_operator(cells, order)
    present = np.array([s is not None and len(s[1]) > 0 for s in samples], bool)
    if not present.any():
        return [None] * T
    offsets = np.zeros(T)
    pens = np.zeros((T, m, m))
    counts = np.zeros(T, np.int64)
    parts_idx, parts_w, parts_y = [], [], []
    for t in np.flatnonzero(present):
        values = np.asarray(samples[t][1], np.float64)
        offsets[t] = float(np.median(values))
        idx, w = _bilinear(samples[t][0], shape, cells)
        parts_idx.append(idx)
        parts_w.append(w)
        parts_y.append(values - offsets[t])
        counts[t] = len(values)
        pens[t] = smooth * len(values) / m * LtL + 1e-9 * np.eye(m)
    idx, w, y = np.concatenate(parts_idx), np.concatenate(parts_w), np.concatenate(parts_y)
    start = np.zeros(T + 1, np.int64)
    np.cumsum(counts, out=start[1:])
    tau = temporal * float(counts[present].mean()) / m * (np.eye(m) - 1.0 / m) if temporal > 0 else None
    robust = np.ones(len(y))
    bounds = part_bounds(start, worker_threads(), MIN_PART_SAMPLES)  # frames, by their samples
    x = np.zeros((T, m))
    for _ in range(max(iters, 1)):
        diag, rhs = np.tile(1e-9 * np.eye(m), (T, 1, 1)), np.zeros((T, m))
        in_parts(partial(_normal_blocks, idx, w, y, robust, start, m=m, diag=diag, rhs=rhs), bounds)
        diag[present] += pens[present]
        if tau is None:
            x = np.linalg.solve(diag, rhs[..., None])[..., 0]
        else:
            links = (np.arange(T) > 0).astype(int) + (np.arange(T) < T - 1)  # neighbours in time
            diag += links[:, None, None] * tau
            x = _block_tridiagonal_solve(diag, -tau, rhs)
        x = np.ascontiguousarray(x)
        in_parts(partial(_reweight, idx, w, y, x, start, scale=scale, robust=robust), bounds)
    return [LogField(x[t], offsets[t], shape, cells) if present[t] else None for t in range(T)]


MIN_PART_SAMPLES = 20000  # the fewest samples worth a thread of their own (a guess, not measured at its break-even)


@njit(cache=True, error_model="numpy", nogil=True)
def _normal_blocks(idx, w, y, robust, start, lo, hi, m, diag, rhs):
    """The robustly weighted normal equations of the frames ``lo`` to ``hi - 1`` without their penalties, written
    into ``diag [T,m,m]`` and ``rhs [T,m]``: samples ``start[t]`` to ``start[t + 1] - 1`` of frame t, their four
    nodes ``idx [R,4]``, bilinear weights ``w [R,4]``, values ``y [R]`` (less the frame's median) and Cauchy weights
    ``robust [R]``. The sums run in the order of a ``bincount`` over the samples' node pairs (the numpy code this
    replaced), so the blocks are the same to the bit."""
    for t in range(lo, hi):
        if start[t + 1] == start[t]:
            continue
        A = diag[t].reshape(m * m)
        A[:] = 0.0
        b = rhs[t]
        for r in range(start[t], start[t + 1]):
            for a in range(4):
                wra = w[r, a] * robust[r]
                row = idx[r, a] * m
                for c in range(4):
                    A[row + idx[r, c]] += wra * w[r, c]
        for r in range(start[t], start[t + 1]):
            for a in range(4):
                b[idx[r, a]] += (w[r, a] * robust[r]) * y[r]


@njit(cache=True, error_model="numpy", nogil=True)
def _reweight(idx, w, y, x, start, lo, hi, scale, robust):
    """The Cauchy weights ``robust [R]`` of the samples of frames ``lo`` to ``hi - 1`` (see :func:`_normal_blocks`)
    from their residuals to the fields ``x [T,m]``: 1 / (1 + (r / scale)^2)."""
    for t in range(lo, hi):
        for r in range(start[t], start[t + 1]):
            f = x[t, idx[r, 0]] * w[r, 0]
            for a in range(1, 4):
                f += x[t, idx[r, a]] * w[r, a]
            q = (f - y[r]) / scale
            robust[r] = 1.0 / (1.0 + q * q)


def _block_tridiagonal_solve(diag: np.ndarray, off: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve the symmetric block-tridiagonal system with blocks ``diag [T,m,m]`` on the diagonal and the same
    ``off [m,m]`` (symmetric) above and below it, for ``rhs [T,m]`` (block Thomas elimination)."""
    T = len(diag)
    d = diag.copy()
    b = rhs.copy()
    for t in range(1, T):
        g = np.linalg.solve(d[t - 1], np.concatenate([off, b[t - 1][:, None]], 1))  # d^-1 [off | b]
        d[t] -= off @ g[:, :-1]
        b[t] -= off @ g[:, -1]
    x = np.zeros_like(rhs)
    x[-1] = np.linalg.solve(d[-1], b[-1])
    for t in range(T - 2, -1, -1):
        x[t] = np.linalg.solve(d[t], b[t] - off @ x[t + 1])
    return x
