"""The Gauss-Newton blocks of stage 2's bundle adjustment compiled for the CPU (numba).

:func:`trackingworld.optim.stage2._linearize` forms, for every observation, the Jacobians of its pixel and depth
residuals with respect to its frame's pose (``[3,6]``) and its point (``[3,3]``), weighs them by the Huber kernels'
IRLS weights and sums them into the pose blocks ``Hcc [T,6,6]``, ``gc [T,6]`` and the point blocks ``Hxx [N,3,3]``,
``gx [N,3]``, keeping the coupling ``Hcx [M,6,3]`` of each observation. In torch that is some sixty operations over
``[M,3,6]`` arrays, which a CPU runs at the speed of its memory; the rigid step's hundred-odd fits of a few hundred
points each spent most of their time there. Here one loop keeps each observation's numbers in registers. Torch
cannot fuse such a loop on a CPU without a C++ compiler at run time (``torch.compile``), hence numba. The torch
function stays the reference and what a CUDA device (or the focal-length unknown) runs; ``tests/test_compiled.py``
holds the two to the same blocks.

Conventions as :mod:`trackingworld.optim.stage2`: world-to-camera ``R [T,3,3]``, ``t [T,3]`` (camera = R X + t,
OpenCV axes), points ``X [N,3]`` metres, observations ``pt, fr [M]``, pixels ``uv [M,2]`` (x right, y down),
depth targets ``depth [M]`` metres; a pose's update is a left perturbation ``(rotation, translation)``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from scipy.linalg import cho_factor, cho_solve
from threadpoolctl import ThreadpoolController


def f64(a) -> np.ndarray:
    """``a`` as a contiguous float64 array (no copy when it already is one): one compiled signature for every call."""
    return np.ascontiguousarray(a, np.float64)


def i64(a) -> np.ndarray:
    """``a`` as a contiguous int64 array (no copy when it already is one)."""
    return np.ascontiguousarray(a, np.int64)


def camera_constants(K: np.ndarray, kernel_focal: float | None = None) -> np.ndarray:
    """The kernels' camera numbers ``[5]``: fx, fy, cx, cy (px) of ``K`` and the focal length (px) of the Huber
    thresholds (``kernel_focal``, None: sqrt(fx fy), as :attr:`trackingworld.optim.stage2.BAProblem.kernel_f`)."""
    fxy = math.sqrt(K[0, 0] * K[1, 1]) if kernel_focal is None else kernel_focal
    return np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], fxy], np.float64)


@njit(cache=True, error_model="numpy", inline="always")
def camera_point(R, t, f, x0, x1, x2):
    """``R[f] X + t[f]`` of the point ``X = (x0, x1, x2)``: its camera coordinates in frame ``f``."""
    return (R[f, 0, 0] * x0 + R[f, 0, 1] * x1 + R[f, 0, 2] * x2 + t[f, 0],
            R[f, 1, 0] * x0 + R[f, 1, 1] * x1 + R[f, 1, 2] * x2 + t[f, 1],
            R[f, 2, 0] * x0 + R[f, 2, 1] * x1 + R[f, 2, 2] * x2 + t[f, 2])


@njit(cache=True, error_model="numpy", inline="always")
def residual(R, t, X, i, f, u, v, d, k, log_dc):
    """One observation's residuals: point ``i`` seen at pixel ``(u, v)`` with depth target ``d`` (metres) in frame
    ``f``. Returns its camera point ``y0, y1, y2``, the depth ``z`` the projection divides by (floored at 1 mm),
    the metres of depth per unit of the depth residual ``ds`` and the residuals: pixels ``r0, r1``, depth ``r2``
    (log ratio, or metres without ``log_dc``), as :func:`trackingworld.optim.stage2.residuals`."""
    y0, y1, y2 = camera_point(R, t, f, X[i, 0], X[i, 1], X[i, 2])
    z = max(y2, 1e-3)
    r0 = k[0] * y0 / z + k[2] - u
    r1 = k[1] * y1 / z + k[3] - v
    if log_dc:
        return y0, y1, y2, z, z, r0, r1, math.log(z) - math.log(max(d, 1e-3))
    return y0, y1, y2, z, 1.0, r0, r1, y2 - d


@njit(cache=True, error_model="numpy", inline="always")
def _huber(r, c):
    """The Huber cost of a residual's magnitude ``r >= 0`` at threshold ``c`` (as
    :func:`trackingworld.optim.stage2._huber`)."""
    return r * r if r <= c else 2 * c * r - c * c


@njit(cache=True, error_model="numpy", nogil=True)
def _cost(R, t, X, pt, fr, uv, depth, dcw, k, weights, offsets, log_dc):
    """The objective (see :func:`cost`)."""
    kf = k[4]
    lba, ldc, lasap = weights[0], weights[1], weights[2]
    M = len(pt)
    total = 0.0
    for m in range(M):
        _, _, _, z, ds, r0, r1, r2 = residual(R, t, X, pt[m], fr[m], uv[m, 0], uv[m, 1], depth[m], k, log_dc)
        e_uv = math.sqrt(r0 * r0 + r1 * r1)
        e_d = abs(r2)
        if not offsets:
            total += lba * e_uv**2 + ldc * dcw[m] * e_d**2
            continue
        total += lba * _huber(e_uv, lasap * z / (2 * lba * kf))
        if ldc > 0:
            total += ldc * dcw[m] * _huber(e_d, lasap * ds / (2 * max(ldc, 1e-12)) / max(dcw[m], 1e-12))
    return total / M if M else math.nan


@njit(cache=True, error_model="numpy", nogil=True)
def _blocks(R, t, X, pt, fr, uv, depth, dcw, k, weights, offsets, log_dc, points_only):
    """The blocks (see :func:`linearize`; ``k`` = fx, fy, cx, cy, the kernel's focal; ``weights`` = lambda_ba,
    lambda_dc, lambda_asap; ``dcw [M]`` the depth term's factor per observation)."""
    fx, fy, kf = k[0], k[1], k[4]
    lba, ldc, lasap = weights[0], weights[1], weights[2]
    M, T, N = len(pt), len(R), len(X)
    Hxx = np.zeros((N, 3, 3))
    gx = np.zeros((N, 3))
    Hcc = np.zeros((0 if points_only else T, 6, 6))
    gc = np.zeros((0 if points_only else T, 6))
    Hcx = np.zeros((0 if points_only else M, 6, 3))
    JY = np.zeros((3, 3))  # d residual / d camera point
    Jx = np.zeros((3, 3))  # ... / d point
    Jc = np.zeros((3, 6))  # ... / d pose
    W = np.zeros(3)
    r = np.zeros(3)
    for m in range(M):
        i, f = pt[m], fr[m]
        y0, y1, y2, z, ds, r[0], r[1], r[2] = residual(R, t, X, i, f, uv[m, 0], uv[m, 1], depth[m], k, log_dc)
        w_uv = 1.0
        w_d = 1.0
        if offsets:  # the Huber kernels' IRLS weights, thresholds from the eliminated offsets (BAProblem.thresholds)
            c_uv = lasap * z / (2 * lba * kf)
            c_d = lasap * ds / (2 * max(ldc, 1e-12)) / max(dcw[m], 1e-12)
            w_uv = min(c_uv / max(math.sqrt(r[0] * r[0] + r[1] * r[1]), 1e-12), 1.0)
            w_d = min(c_d / max(abs(r[2]), 1e-12), 1.0)
        W[0] = lba * w_uv / M
        W[1] = W[0]
        W[2] = ldc * dcw[m] * w_d / M
        JY[0, 0] = fx / z
        JY[0, 2] = -fx * y0 / (z * z)
        JY[1, 1] = fy / z
        JY[1, 2] = -fy * y1 / (z * z)
        JY[2, 2] = 1.0 / ds
        for a in range(3):
            for b in range(3):
                Jx[a, b] = JY[a, 0] * R[f, 0, b] + JY[a, 1] * R[f, 1, b] + JY[a, 2] * R[f, 2, b]
        for a in range(3):
            gx[i, 0] += Jx[a, 0] * W[a] * r[a]
            gx[i, 1] += Jx[a, 1] * W[a] * r[a]
            gx[i, 2] += Jx[a, 2] * W[a] * r[a]
            for b in range(3):
                wj = W[a] * Jx[a, b]
                for c in range(3):
                    Hxx[i, b, c] += Jx[a, c] * wj
        if points_only:
            continue
        # d Y / d pose = [-[Y]x, I] (lie.pose_jacobian)
        for a in range(3):
            Jc[a, 0] = -JY[a, 1] * y2 + JY[a, 2] * y1
            Jc[a, 1] = JY[a, 0] * y2 - JY[a, 2] * y0
            Jc[a, 2] = -JY[a, 0] * y1 + JY[a, 1] * y0
            Jc[a, 3] = JY[a, 0]
            Jc[a, 4] = JY[a, 1]
            Jc[a, 5] = JY[a, 2]
        for a in range(3):
            wr = W[a] * r[a]
            for b in range(6):
                gc[f, b] += Jc[a, b] * wr
                wj = W[a] * Jc[a, b]
                for c in range(6):
                    Hcc[f, b, c] += Jc[a, c] * wj
                for c in range(3):
                    Hcx[m, b, c] += Jx[a, c] * wj
    return Hcc, Hxx, Hcx, gc, gx


def _arrays(R, t, X, pt, fr, uv, depth, K, weights, offsets, log_dc, kernel_focal, dc_weight) -> tuple:
    """The kernels' arguments from :func:`linearize`'s and :func:`cost`'s, in the types they are compiled for."""
    dcw = np.ones(len(pt)) if dc_weight is None else f64(dc_weight)
    return (f64(R), f64(t), f64(X), i64(pt), i64(fr), f64(uv), f64(depth), dcw, camera_constants(K, kernel_focal),
            f64(weights), bool(offsets), bool(log_dc))


def linearize(R: np.ndarray, t: np.ndarray, X: np.ndarray, pt: np.ndarray, fr: np.ndarray, uv: np.ndarray,
              depth: np.ndarray, K: np.ndarray, weights: tuple[float, float, float], offsets: bool = True,
              log_dc: bool = True, kernel_focal: float | None = None, dc_weight: np.ndarray | None = None,
              points_only: bool = False):
    """Gauss-Newton blocks ``(Hcc [T,6,6], Hxx [N,3,3], Hcx [M,6,3], gc [T,6], gx [N,3])`` of the IRLS-weighted
    stage-2 objective at poses ``R, t`` and points ``X`` (float64 arrays; ``weights`` = lambda_ba, lambda_dc,
    lambda_asap; ``offsets``, ``log_dc``, ``kernel_focal`` and ``dc_weight [M]`` as in
    :class:`trackingworld.optim.stage2.BAProblem`). With ``points_only`` the pose blocks are empty (first
    dimension 0): what a fit of the points under fixed poses needs."""
    return _blocks(*_arrays(R, t, X, pt, fr, uv, depth, K, weights, offsets, log_dc, kernel_focal, dc_weight),
                   bool(points_only))


def cost(R: np.ndarray, t: np.ndarray, X: np.ndarray, pt: np.ndarray, fr: np.ndarray, uv: np.ndarray,
         depth: np.ndarray, K: np.ndarray, weights: tuple[float, float, float], offsets: bool = True,
         log_dc: bool = True, kernel_focal: float | None = None, dc_weight: np.ndarray | None = None) -> float:
    """The stage-2 objective :func:`trackingworld.optim.stage2.loss` (its mean over the observations, the offsets
    eliminated), arguments as :func:`linearize`'s."""
    return _cost(*_arrays(R, t, X, pt, fr, uv, depth, K, weights, offsets, log_dc, kernel_focal, dc_weight))


@njit(cache=True, error_model="numpy", nogil=True)
def _chol3(H, out):
    """``out [3,3]`` <- the lower Cholesky factor of ``H [3,3]``; False where H is not positive definite."""
    out[:] = 0.0
    if not H[0, 0] > 0:
        return False
    out[0, 0] = math.sqrt(H[0, 0])
    out[1, 0] = H[1, 0] / out[0, 0]
    out[2, 0] = H[2, 0] / out[0, 0]
    d = H[1, 1] - out[1, 0] ** 2
    if not d > 0:
        return False
    out[1, 1] = math.sqrt(d)
    out[2, 1] = (H[2, 1] - out[2, 0] * out[1, 0]) / out[1, 1]
    d = H[2, 2] - out[2, 0] ** 2 - out[2, 1] ** 2
    if not d > 0:
        return False
    out[2, 2] = math.sqrt(d)
    return True


@njit(cache=True, error_model="numpy", nogil=True)
def _chol3_solve(L, b, out):
    """``out [3]`` <- ``(L L^T)^-1 b`` for a lower triangular ``L [3,3]``."""
    y0 = b[0] / L[0, 0]
    y1 = (b[1] - L[1, 0] * y0) / L[1, 1]
    y2 = (b[2] - L[2, 0] * y0 - L[2, 1] * y1) / L[2, 2]
    out[2] = y2 / L[2, 2]
    out[1] = (y1 - L[2, 1] * out[2]) / L[1, 1]
    out[0] = (y0 - L[1, 0] * out[1] - L[2, 0] * out[2]) / L[0, 0]


@njit(cache=True, error_model="numpy", nogil=True)
def _damped(H, mu, out):
    """``out`` <- the square ``H`` damped as :func:`trackingworld.optim.stage2._damp`: ``mu`` times its diagonal
    plus 1e-12 times (1 + the diagonal's largest magnitude) added to the diagonal."""
    top = 0.0
    for i in range(H.shape[0]):
        top = max(top, abs(H[i, i]))
    out[:] = H
    for i in range(H.shape[0]):
        out[i, i] += mu * H[i, i] + 1e-12 * (1 + top)


@njit(cache=True, error_model="numpy", nogil=True)
def _apply(L, kind, b, out):
    """``out [3]`` <- ``Hxx^-1 b`` for a point block factored by :func:`_reduce` (``kind`` 0: ``L`` its Cholesky factor;
    1: ``L`` = V lam^-1/2 of its eigen-decomposition, so that the inverse is ``L L^T``)."""
    if kind == 0:
        _chol3_solve(L, b, out)
        return
    for j in range(3):
        out[j] = 0.0
    for c in range(3):
        s = L[0, c] * b[0] + L[1, c] * b[1] + L[2, c] * b[2]
        for j in range(3):
            out[j] += L[j, c] * s


@njit(cache=True, error_model="numpy", nogil=True)
def _reduce(Hcc, Hxx, Hcx, gc, gx, pt, fr, mu, free):
    """The points eliminated from one damped step (see :func:`schur_step`): the whitened couplings ``G [M,6,3]``
    (one per observation, such that the reduced system is ``D - sum over points of G_m G_m'^T`` over each pair of
    its observations), the damped pose blocks as a dense ``D [6T,6T]``, the point blocks' factors, ``y = Hxx^-1 gx``
    and the reduced right-hand side. A point block that Cholesky finds not positive definite (a point seen along
    one ray without the depth term) is factored by its eigen-decomposition, its eigenvalues floored at 1e-300, as
    :func:`trackingworld.optim.stage2._schur_step` does for every block."""
    T, N, M = len(Hcc), len(Hxx), len(pt)
    L = np.zeros((N, 3, 3))
    kind = np.zeros(N, np.int64)
    y = np.zeros((N, 3))
    Hd = np.zeros((3, 3))
    for i in range(N):
        _damped(Hxx[i], mu, Hd)
        if not _chol3(Hd, L[i]):
            lam, V = np.linalg.eigh(Hd)
            kind[i] = 1
            for c in range(3):
                s = 1.0 / math.sqrt(max(lam[c], 1e-300))
                for j in range(3):
                    L[i, j, c] = V[j, c] * s
        _apply(L[i], kind[i], gx[i], y[i])
    # each observation's Hcx whitened by its point's factor: L^-1 Hcx^T for a Cholesky factor, L^T Hcx^T for an
    # eigen one, so that G G^T summed over a point's pairs is Hcx Hxx^-1 Hcx^T
    G = np.empty((M, 6, 3))
    rhs = np.zeros((T, 6))
    for m in range(M):
        i, f = pt[m], fr[m]
        for k in range(6):
            if kind[i] == 0:
                g0 = Hcx[m, k, 0] / L[i, 0, 0]
                g1 = (Hcx[m, k, 1] - L[i, 1, 0] * g0) / L[i, 1, 1]
                g2 = (Hcx[m, k, 2] - L[i, 2, 0] * g0 - L[i, 2, 1] * g1) / L[i, 2, 2]
            else:
                g0 = L[i, 0, 0] * Hcx[m, k, 0] + L[i, 1, 0] * Hcx[m, k, 1] + L[i, 2, 0] * Hcx[m, k, 2]
                g1 = L[i, 0, 1] * Hcx[m, k, 0] + L[i, 1, 1] * Hcx[m, k, 1] + L[i, 2, 1] * Hcx[m, k, 2]
                g2 = L[i, 0, 2] * Hcx[m, k, 0] + L[i, 1, 2] * Hcx[m, k, 1] + L[i, 2, 2] * Hcx[m, k, 2]
            G[m, k, 0] = g0
            G[m, k, 1] = g1
            G[m, k, 2] = g2
            rhs[f, k] += Hcx[m, k, 0] * y[i, 0] + Hcx[m, k, 1] * y[i, 1] + Hcx[m, k, 2] * y[i, 2]
    Hd6 = np.zeros((6, 6))
    D = np.zeros((6 * T, 6 * T))
    for f in range(T):
        _damped(Hcc[f], mu, Hd6)
        for a in range(6):
            rhs[f, a] = -(gc[f, a] - rhs[f, a]) if free[f] else 0.0
            for b in range(6):
                D[6 * f + a, 6 * f + b] = Hd6[a, b]
    return G, D, L, kind, y, rhs


@njit(cache=True, nogil=True)
def _coupling(G, pt, fr, N, T):
    """``B^T [6T, 3N]``: each observation's ``G`` at (its frame, its point), so that ``B^T B`` is the sum of
    :func:`_reduce`'s pairs (a point has one observation per frame: each block is written once); ``B^T B`` is
    then numpy's product of it with its transpose."""
    Bt = np.zeros((6 * T, 3 * N))
    for m in range(len(pt)):
        i, f = pt[m], fr[m]
        for k in range(6):
            for j in range(3):
                Bt[6 * f + k, 3 * i + j] = G[m, k, j]
    return Bt


@njit(cache=True, error_model="numpy", nogil=True)
def _subtract_pairs(G, pt, fr, N, A):
    """``A [6T,6T]`` minus, for every point and every pair of its observations ``m, m'`` in frames ``f >= f'``,
    ``G_m G_m'^T`` at block (f, f'): the lower triangle of ``A - B^T B`` (:func:`_coupling`) in the work of the
    pairs alone, for points seen in few of the frames."""
    cnt = np.zeros(N + 1, np.int64)
    for m in range(len(pt)):
        cnt[pt[m] + 1] += 1
    start = np.cumsum(cnt)
    obs = np.empty(len(pt), np.int64)
    nxt = start[:-1].copy()
    for m in range(len(pt)):
        obs[nxt[pt[m]]] = m
        nxt[pt[m]] += 1
    for i in range(N):
        for o1 in range(start[i], start[i + 1]):
            m1 = obs[o1]
            r = 6 * fr[m1]
            for o2 in range(start[i], start[i + 1]):
                m2 = obs[o2]
                if fr[m2] > fr[m1]:
                    continue
                c = 6 * fr[m2]
                for a in range(6):
                    g0, g1, g2 = G[m1, a, 0], G[m1, a, 1], G[m1, a, 2]
                    for b in range(6):
                        A[r + a, c + b] -= g0 * G[m2, b, 0] + g1 * G[m2, b, 1] + g2 * G[m2, b, 2]


@njit(cache=True, error_model="numpy", nogil=True)
def _back(L, kind, y, Hcx, dc, pt, fr):
    """The points' step ``dx [N,3]`` given the poses' ``dc [T,6]``: ``-Hxx^-1 (gx + sum Hcx^T dc)`` (``y`` =
    ``Hxx^-1 gx``)."""
    N = len(L)
    back = np.zeros((N, 3))
    for m in range(len(pt)):
        i, f = pt[m], fr[m]
        for j in range(3):
            s = 0.0
            for k in range(6):
                s += Hcx[m, k, j] * dc[f, k]
            back[i, j] += s
    dx = np.zeros((N, 3))
    tmp = np.zeros(3)
    for i in range(N):
        _apply(L[i], kind[i], back[i], tmp)
        for j in range(3):
            dx[i, j] = -(y[i, j] + tmp[j])
    return dx


def reduced_cost(pt: np.ndarray, n_points: int, n_frames: int) -> tuple[str, float]:
    """How :func:`schur_step` forms the reduced pose system of a problem (observations ``pt [M]`` of ``n_points``
    points in ``n_frames`` frames) and what that costs, in multiply-adds of BLAS: ``("blas", 3N (6T)^2 / 2)``, the
    product ``B^T B`` (:func:`_coupling`, dense, in BLAS's symmetric rank-k update), or ``("pairs", PAIR_COST x 54
    sum k (k + 1))`` (:func:`_subtract_pairs`, a point seen in k frames), whichever is cheaper; ``B`` only up to
    :data:`COUPLING_ENTRIES` numbers."""
    k = np.bincount(pt, minlength=n_points).astype(np.float64)
    pairs = PAIR_COST * 54.0 * float((k * (k + 1)).sum())
    blas = 1.5 * n_points * (6.0 * n_frames) ** 2
    if blas <= pairs and 18.0 * n_points * n_frames <= COUPLING_ENTRIES:
        return "blas", blas
    return "pairs", pairs


def schur_step(Hcc, Hxx, Hcx, gc, gx, pt, fr, mu: float, free: np.ndarray, how: str = "blas"):
    """One damped Gauss-Newton step of :func:`trackingworld.optim.stage2._schur_step` (no focal unknown), the
    reduced pose system formed densely: ``(dc [T,6], dx [N,3])``, or None where that system is not positive
    definite (the caller's PCG handles it). Float64 arrays as :func:`linearize` gives them, ``pt, fr [M]`` int64;
    ``free [T]`` bool, the frames that move. The reduced system is ``D - sum Hcx Hxx^-1 Hcx^T`` (``D`` the damped
    pose blocks), the sum formed as :func:`reduced_cost` says (``how``): ``"blas"`` as ``B^T B``, its product left
    to BLAS, which no hand-written loop matches where the points are seen in most frames, or ``"pairs"`` over each
    point's pairs of observations, far less work where they are seen in few (stage 2's thousands of static points
    in a long video); then a Cholesky factorisation of its lower triangle."""
    G, A, L, kind, y, rhs = _reduce(Hcc, Hxx, Hcx, gc, gx, pt, fr, float(mu), free)
    N, T = len(Hxx), len(Hcc)
    with _blas_threads(1):
        if how == "blas":
            Bt = _coupling(G, pt, fr, N, T)
            # B^T B: numpy's product of an array with its transpose is BLAS's symmetric rank-k update, its lower
            # triangle scipy's dsyrk's to the bit (this replaced it), and numpy lets go of the GIL in it
            A -= Bt @ Bt.T
        else:
            _subtract_pairs(G, pt, fr, N, A)
        fixed = np.repeat(~free, 6)
        A[fixed] = 0.0
        A[:, fixed] = 0.0
        A[fixed, fixed] = 1.0
        try:  # the lower triangle only
            c = cho_factor(A, lower=True, check_finite=False, overwrite_a=True)
        except np.linalg.LinAlgError:
            return None
        dc = cho_solve(c, rhs.reshape(-1), check_finite=False).reshape(-1, 6)
    return dc, _back(L, kind, y, Hcx, dc, pt, fr)


# BLAS (numpy's and scipy's OpenBLAS) runs on one thread in the step: OpenBLAS's threads, woken for each small
# system, cost more than they saved (stop 69, 2-core machine, a rigid fit's 800 points x 30 frames, 7.8e7
# multiply-adds: the whole step 13.7 ms on 2 threads, 4.9 ms on one), and a second pool of threads spinning beside
# torch's slowed torch's own operations after each step (stage 2 of a 30-frame 320x240 scene: its objective 3 -> 39
# ms per evaluation). On one thread the symmetric product still beat torch's on two at every size (stop 70,
# ``B^T B`` of 600 x 720 / 2400 x 720 / 24000 x 720: 11.7 / 40.4 / 428 ms against torch's 16.7 / 44.5 / 401 ms)
# how many of BLAS's multiply-adds cost as much as one of :func:`_subtract_pairs`': stop 70, 2-core machine, the
# steps of a 120-frame video (the rigid step's fits, stage 2's 8,161 points), the symmetric product at 0.9-1.7e10
# multiply-adds a second, the pairs at 1.5-2.7e9, 6.8x slower on the median of 30 problems
PAIR_COST = 7.0
COUPLING_ENTRIES = 1e7  # the most numbers in B (3N x 6T, 80 MB in float64) of the "blas" way
_controller = None


def _blas_threads(n: int):
    """A context in which BLAS (numpy's and scipy's OpenBLAS) runs on at most ``n`` threads."""
    global _controller
    if _controller is None:
        _controller = ThreadpoolController()
    return _controller.limit(limits=n, user_api="blas")
