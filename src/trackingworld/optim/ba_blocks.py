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
import torch
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


@njit(cache=True, error_model="numpy")
def _blocks(R, t, X, pt, fr, uv, depth, dcw, k, weights, offsets, log_dc, points_only):
    """The blocks (see :func:`linearize`; ``k`` = fx, fy, cx, cy, the kernel's focal; ``weights`` = lambda_ba,
    lambda_dc, lambda_asap; ``dcw [M]`` the depth term's factor per observation)."""
    fx, fy, cx, cy, kf = k[0], k[1], k[2], k[3], k[4]
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
        y0, y1, y2 = camera_point(R, t, f, X[i, 0], X[i, 1], X[i, 2])
        z = max(y2, 1e-3)
        r[0] = fx * y0 / z + cx - uv[m, 0]
        r[1] = fy * y1 / z + cy - uv[m, 1]
        if log_dc:
            r[2] = math.log(z) - math.log(max(depth[m], 1e-3))
            ds = z
        else:
            r[2] = y2 - depth[m]
            ds = 1.0
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


def linearize(R: np.ndarray, t: np.ndarray, X: np.ndarray, pt: np.ndarray, fr: np.ndarray, uv: np.ndarray,
              depth: np.ndarray, K: np.ndarray, weights: tuple[float, float, float], offsets: bool = True,
              log_dc: bool = True, kernel_focal: float | None = None, dc_weight: np.ndarray | None = None,
              points_only: bool = False):
    """Gauss-Newton blocks ``(Hcc [T,6,6], Hxx [N,3,3], Hcx [M,6,3], gc [T,6], gx [N,3])`` of the IRLS-weighted
    stage-2 objective at poses ``R, t`` and points ``X`` (float64 arrays; ``weights`` = lambda_ba, lambda_dc,
    lambda_asap; ``offsets``, ``log_dc``, ``kernel_focal`` and ``dc_weight [M]`` as in
    :class:`trackingworld.optim.stage2.BAProblem`). With ``points_only`` the pose blocks are empty (first
    dimension 0): what a fit of the points under fixed poses needs."""
    dcw = np.ones(len(pt)) if dc_weight is None else f64(dc_weight)
    return _blocks(f64(R), f64(t), f64(X), i64(pt), i64(fr), f64(uv), f64(depth), dcw,
                   camera_constants(K, kernel_focal), f64(weights), bool(offsets), bool(log_dc), bool(points_only))


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def _chol3_solve(L, b, out):
    """``out [3]`` <- ``(L L^T)^-1 b`` for a lower triangular ``L [3,3]``."""
    y0 = b[0] / L[0, 0]
    y1 = (b[1] - L[1, 0] * y0) / L[1, 1]
    y2 = (b[2] - L[2, 0] * y0 - L[2, 1] * y1) / L[2, 2]
    out[2] = y2 / L[2, 2]
    out[1] = (y1 - L[2, 1] * out[2]) / L[1, 1]
    out[0] = (y0 - L[1, 0] * out[1] - L[2, 0] * out[2]) / L[0, 0]


@njit(cache=True, error_model="numpy")
def _damped(H, mu, out):
    """``out`` <- the square ``H`` damped as :func:`trackingworld.optim.stage2._damp`: ``mu`` times its diagonal
    plus 1e-12 times (1 + the diagonal's largest magnitude) added to the diagonal."""
    top = 0.0
    for i in range(H.shape[0]):
        top = max(top, abs(H[i, i]))
    out[:] = H
    for i in range(H.shape[0]):
        out[i, i] += mu * H[i, i] + 1e-12 * (1 + top)


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def _reduce(Hcc, Hxx, Hcx, gc, gx, pt, fr, mu, free):
    """The points eliminated from one damped step (see :func:`schur_step`). A point block that Cholesky finds not
    positive definite (a point seen along one ray without the depth term) is factored by its eigen-decomposition,
    its eigenvalues floored at 1e-300, as :func:`trackingworld.optim.stage2._schur_step` does for every block."""
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
    # B [3N, 6T]: each observation's block at (its point, its frame) such that B^T B = sum Hcx Hxx^-1 Hcx^T:
    # L^-1 Hcx^T for a Cholesky factor, L^T Hcx^T for an eigen one
    B = np.zeros((3 * N, 6 * T))
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
            B[3 * i, 6 * f + k] = g0
            B[3 * i + 1, 6 * f + k] = g1
            B[3 * i + 2, 6 * f + k] = g2
            rhs[f, k] += Hcx[m, k, 0] * y[i, 0] + Hcx[m, k, 1] * y[i, 1] + Hcx[m, k, 2] * y[i, 2]
    Hd6 = np.zeros((6, 6))
    D = np.zeros((6 * T, 6 * T))
    for f in range(T):
        _damped(Hcc[f], mu, Hd6)
        for a in range(6):
            rhs[f, a] = -(gc[f, a] - rhs[f, a]) if free[f] else 0.0
            for b in range(6):
                D[6 * f + a, 6 * f + b] = Hd6[a, b]
    return B, D, L, kind, y, rhs


@njit(cache=True, error_model="numpy")
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


def schur_step(Hcc, Hxx, Hcx, gc, gx, pt, fr, mu: float, free: np.ndarray):
    """One damped Gauss-Newton step of :func:`trackingworld.optim.stage2._schur_step` (no focal unknown), the
    reduced pose system formed densely: ``(dc [T,6], dx [N,3])``, or None where that system is not positive
    definite (the caller's PCG handles it). Float64 arrays as :func:`linearize` gives
    them, ``pt, fr [M]`` int64; ``free [T]`` bool, the frames that move. The reduced system is ``D - B^T B``
    (``D`` the damped pose blocks, ``B`` the points' couplings whitened by their blocks' factors), its product left
    to BLAS, which no hand-written loop matches."""
    B, A, L, kind, y, rhs = _reduce(Hcc, Hxx, Hcx, gc, gx, pt, fr, float(mu), free)
    with _blas_threads(1):
        if B.shape[0] * B.shape[1] ** 2 < SMALL_PRODUCT:
            A -= B.T @ B
        else:  # torch's threads, the pool the rest of the step uses (see SMALL_PRODUCT)
            Bt = torch.from_numpy(B)
            A -= (Bt.T @ Bt).numpy()
        fixed = np.repeat(~free, 6)
        A[fixed] = 0.0
        A[:, fixed] = 0.0
        A[fixed, fixed] = 1.0
        try:
            c = cho_factor(0.5 * (A + A.T), lower=True, check_finite=False)
        except np.linalg.LinAlgError:
            return None
        dc = cho_solve(c, rhs.reshape(-1), check_finite=False).reshape(-1, 6)
    return dc, _back(L, kind, y, Hcx, dc, pt, fr)


# numpy's and scipy's BLAS run on one thread here: OpenBLAS's threads, woken for each small system, cost more than
# they saved (stop 69, 2-core machine, a rigid fit's 800 points x 30 frames, 7.8e7 multiply-adds: the whole step
# 13.7 ms on 2 threads, 4.9 ms on one), and a second pool of threads spinning beside torch's slowed torch's own
# operations after each step (stage 2 of a 30-frame 320x240 scene: its objective 3 -> 39 ms per evaluation). A
# product of more than this many multiply-adds goes to torch, on torch's threads
SMALL_PRODUCT = 2e8
_controller = None


def _blas_threads(n: int):
    """A context in which BLAS (numpy's and scipy's OpenBLAS) runs on at most ``n`` threads."""
    global _controller
    if _controller is None:
        _controller = ThreadpoolController()
    return _controller.limit(limits=n, user_api="blas")
