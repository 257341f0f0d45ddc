"""The static tests' point fits compiled for the CPU in float32 (numba): :func:`trackingworld.optim.stage2.fit_points`
on a CPU float32 problem.

After stage 2 every track outside it is judged by its best static point with the poses held
(:mod:`trackingworld.optim.static_tests`): the initial point (the mean of its prior-depth back-projections), then
a few Gauss-Newton steps on stage 2's objective with the offsets eliminated (the Huber kernels as IRLS weights),
each a 3x3 system per track. The tests run in float32 (a threshold at epsilon = 0.1 m needs no more), and in
torch each step is some forty operations over ``[M,3,3]`` arrays of every observation, which a CPU runs at the
speed of its memory: at 854x480 these fits were the largest torch cost left in the run (12.2 s of the 78 s of
optimisation in a profiled run). Here
each track's few observations stay in cache through all its steps.

Why float32 and the torch formulas operation by operation: the static tests decide labels at thresholds, and the
verdicts of some tracks sit on them. Stop 69 ran these fits in float64 through the compiled blocks and moved
world 3D accuracy on two of forty-seven scenes by 0.35-0.50 (``docs/results.md``): the pipeline downstream of a
flipped verdict is chaotic (a rigid group's random draw of tracks). So this kernel keeps the reference's float32
and its order of operations (each product and sum rounded to float32 as torch's are, the observations summed in
their order as ``index_add_`` sums them, LU with partial pivoting as LAPACK's ``sgesv``), and differs from it only
where torch's own kernels round differently (vectorised ``log``, the order inside a batched 3x3 product): points
within a few float32 ulps, ``tests/test_compiled.py``. Hence also the point blocks' nine entries written out
rather than their six of a symmetric matrix: torch's batched product rounds ``H[0,1]`` and ``H[1,0]`` apart.
The torch function stays the reference and what CUDA and
float64 run.

Conventions as :mod:`trackingworld.optim.stage2`: world-to-camera ``R [T,3,3]``, ``t [T,3]`` (camera = R X + t,
OpenCV axes), observations ``pt, fr [M]`` (sorted by point), pixels ``uv [M,2]`` (x right, y down), depth targets
``depth [M]`` metres.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from trackingworld.optim.parallel import in_parts, part_bounds, worker_threads

# the fewest observations worth a thread of their own: on random 30-frame problems one thread and two took the
# same 0.46 ms at 1,196 observations, 1.60 against 1.33 ms at 4,821, 26.7 against 14.5 ms at 48,098
MIN_PART_OBS = 8000


@njit(cache=True, error_model="numpy", inline="always")
def _solve3_lu(A, b):
    """``A^-1 b`` of a 3x3 system ``A [3,3]``, ``b [3]`` (overwritten) by LU with partial pivoting, as LAPACK's
    getrf / getrs (the column below a pivot scaled by its reciprocal), in float32."""
    one = np.float32(1.0)
    for j in range(3):
        p = j
        for i in range(j + 1, 3):
            if abs(A[i, j]) > abs(A[p, j]):
                p = i
        if p != j:
            for c in range(3):
                A[j, c], A[p, c] = A[p, c], A[j, c]
            b[j], b[p] = b[p], b[j]
        if A[j, j] != 0:
            r = one / A[j, j]
            for i in range(j + 1, 3):
                A[i, j] = A[i, j] * r
        for i in range(j + 1, 3):
            for c in range(j + 1, 3):
                A[i, c] = A[i, c] - A[i, j] * A[j, c]
    for i in range(1, 3):  # forward substitution (unit lower triangle)
        for c in range(i):
            b[i] = b[i] - A[i, c] * b[c]
    for i in range(2, -1, -1):  # back substitution
        for c in range(i + 1, 3):
            b[i] = b[i] - A[i, c] * b[c]
        b[i] = b[i] / A[i, i]
    return b[0], b[1], b[2]


@njit(cache=True, error_model="numpy", nogil=True)
def _fit_points(R, t, k, w, starts, fr, uv, depth, dcw, has_dcw, offsets, log_dc, iters, lo, hi, X):
    """The points ``lo`` to ``hi - 1`` (see :func:`fit_points`), written into ``X [N,3]``. float32 arrays
    throughout; ``k`` = fx, fy, cx, cy, the kernel's focal (float32); ``w`` = lambda_ba, lambda_dc, lambda_asap, M,
    2 * lambda_ba, 2 * max(lambda_dc, 1e-12) as float32, as torch converts each Python number it meets. ``starts
    [N+1]``: each point's first observation."""
    f32 = np.float32
    zero, one, floor_z, tiny = f32(0.0), f32(1.0), f32(1e-3), f32(1e-12)
    damp, floor_s = f32(1e-6), f32(1e-30)
    fx, fy, cx, cy, kf = k[0], k[1], k[2], k[3], k[4]
    lba, ldc, lasap, Mf, two_lba, two_ldc = w[0], w[1], w[2], w[3], w[4], w[5]
    den_uv = two_lba * kf  # (2 * lambda_ba) * kernel_f, a float32 product as in torch
    A = np.empty((3, 3), np.float32)  # each step's system
    b = np.empty(3, np.float32)
    for i in range(lo, hi):
        s, e = starts[i], starts[i + 1]
        if e == s:
            continue
        # init_points: the mean of the back-projections at the prior depth
        s0, s1, s2 = zero, zero, zero
        for m in range(s, e):
            f, d = fr[m], depth[m]
            c0 = (uv[m, 0] - cx) / fx * d - t[f, 0]
            c1 = (uv[m, 1] - cy) / fy * d - t[f, 1]
            c2 = d - t[f, 2]
            s0 += R[f, 0, 0] * c0 + R[f, 1, 0] * c1 + R[f, 2, 0] * c2
            s1 += R[f, 0, 1] * c0 + R[f, 1, 1] * c1 + R[f, 2, 1] * c2
            s2 += R[f, 0, 2] * c0 + R[f, 1, 2] * c1 + R[f, 2, 2] * c2
        n = f32(e - s)
        x0, x1, x2 = s0 / n, s1 / n, s2 / n
        for _ in range(iters):
            h00 = h01 = h02 = h10 = h11 = h12 = h20 = h21 = h22 = zero
            g0 = g1 = g2 = zero
            for m in range(s, e):
                f = fr[m]
                y0 = R[f, 0, 0] * x0 + R[f, 0, 1] * x1 + R[f, 0, 2] * x2 + t[f, 0]
                y1 = R[f, 1, 0] * x0 + R[f, 1, 1] * x1 + R[f, 1, 2] * x2 + t[f, 1]
                y2 = R[f, 2, 0] * x0 + R[f, 2, 1] * x1 + R[f, 2, 2] * x2 + t[f, 2]
                z = max(y2, floor_z)
                r0 = fx * y0 / z + cx - uv[m, 0]
                r1 = fy * y1 / z + cy - uv[m, 1]
                ds = z if log_dc else one
                if log_dc:
                    r2 = f32(math.log(z)) - f32(math.log(max(depth[m], floor_z)))
                else:
                    r2 = y2 - depth[m]
                ldc_m = ldc * dcw[m] if has_dcw else ldc
                w_uv = one
                w_d = one
                if offsets:
                    c_uv = lasap * z / den_uv
                    c_d = lasap * ds / two_ldc
                    if has_dcw:
                        c_d = c_d / max(dcw[m], tiny)
                    nrm = f32(math.sqrt(float(r0) * float(r0) + float(r1) * float(r1)))
                    w_uv = min(c_uv / max(nrm, tiny), one)
                    w_d = min(c_d / max(abs(r2), tiny), one)
                W0 = lba * w_uv / Mf
                W2 = ldc_m * w_d / Mf
                j00 = fx / z
                j02 = -fx * y0 / (z * z)
                j11 = fy / z
                j12 = -fy * y1 / (z * z)
                j22 = one / ds
                # Jx = JY @ R[f] (JY's zeros included, as the batched product has them)
                a00 = j00 * R[f, 0, 0] + zero * R[f, 1, 0] + j02 * R[f, 2, 0]
                a01 = j00 * R[f, 0, 1] + zero * R[f, 1, 1] + j02 * R[f, 2, 1]
                a02 = j00 * R[f, 0, 2] + zero * R[f, 1, 2] + j02 * R[f, 2, 2]
                a10 = zero * R[f, 0, 0] + j11 * R[f, 1, 0] + j12 * R[f, 2, 0]
                a11 = zero * R[f, 0, 1] + j11 * R[f, 1, 1] + j12 * R[f, 2, 1]
                a12 = zero * R[f, 0, 2] + j11 * R[f, 1, 2] + j12 * R[f, 2, 2]
                a20 = zero * R[f, 0, 0] + zero * R[f, 1, 0] + j22 * R[f, 2, 0]
                a21 = zero * R[f, 0, 1] + zero * R[f, 1, 1] + j22 * R[f, 2, 1]
                a22 = zero * R[f, 0, 2] + zero * R[f, 1, 2] + j22 * R[f, 2, 2]
                b00, b01, b02 = W0 * a00, W0 * a01, W0 * a02  # W J
                b10, b11, b12 = W0 * a10, W0 * a11, W0 * a12
                b20, b21, b22 = W2 * a20, W2 * a21, W2 * a22
                h00 += a00 * b00 + a10 * b10 + a20 * b20
                h01 += a00 * b01 + a10 * b11 + a20 * b21
                h02 += a00 * b02 + a10 * b12 + a20 * b22
                h10 += a01 * b00 + a11 * b10 + a21 * b20
                h11 += a01 * b01 + a11 * b11 + a21 * b21
                h12 += a01 * b02 + a11 * b12 + a21 * b22
                h20 += a02 * b00 + a12 * b10 + a22 * b20
                h21 += a02 * b01 + a12 * b11 + a22 * b21
                h22 += a02 * b02 + a12 * b12 + a22 * b22
                g0 += b00 * r0 + b10 * r1 + b20 * r2
                g1 += b01 * r0 + b11 * r1 + b21 * r2
                g2 += b02 * r0 + b12 * r1 + b22 * r2
            scale = max(max(max(h00, h11), h22), floor_s)
            dd = damp * scale
            A[0, 0], A[0, 1], A[0, 2] = h00 + dd, h01, h02
            A[1, 0], A[1, 1], A[1, 2] = h10, h11 + dd, h12
            A[2, 0], A[2, 1], A[2, 2] = h20, h21, h22 + dd
            b[0], b[1], b[2] = g0, g1, g2
            d0, d1, d2 = _solve3_lu(A, b)
            x0, x1, x2 = x0 - d0, x1 - d1, x2 - d2
        X[i, 0], X[i, 1], X[i, 2] = x0, x1, x2


def fit_points(R: np.ndarray, t: np.ndarray, pt: np.ndarray, fr: np.ndarray, uv: np.ndarray, depth: np.ndarray,
               K: np.ndarray, weights: tuple[float, float, float], offsets: bool, log_dc: bool,
               kernel_focal: float | None, dc_weight: np.ndarray | None, n_points: int, iters: int = 6) -> np.ndarray:
    """Every point's static fit with the poses held, in float32: ``[n_points,3]`` world metres. Poses ``R [T,3,3]``,
    ``t [T,3]`` (world-to-camera), the observations' points and frames ``pt, fr [M]``, pixels ``uv [M,2]``, depth
    targets ``depth [M]`` metres, ``K [3,3]``, ``weights`` = lambda_ba, lambda_dc, lambda_asap; ``offsets``,
    ``log_dc``, ``kernel_focal`` (px, None: K's), per-observation depth weights ``dc_weight [M]`` (None: 1) and
    ``iters`` as :func:`trackingworld.optim.stage2.fit_points`, whose numbers these are (the problem's arguments in
    the order of ``stage2._problem_args``). A point without observations is 0."""
    f32 = np.float32
    pt = np.asarray(pt, np.int64)
    # the observations by point, each point's in their order (a problem of stage2.BAProblem.from_tracks already is)
    order = np.argsort(pt, kind="stable") if len(pt) > 1 and np.any(pt[1:] < pt[:-1]) else slice(None)
    starts = np.zeros(n_points + 1, np.int64)
    np.cumsum(np.bincount(pt, minlength=n_points), out=starts[1:])
    K32 = np.asarray(K, f32)
    kf = np.sqrt(K32[0, 0] * K32[1, 1]) if kernel_focal is None else f32(kernel_focal)
    k = np.array([K32[0, 0], K32[1, 1], K32[0, 2], K32[1, 2], kf], f32)
    lba, ldc, lasap = weights
    w = np.array([lba, ldc, lasap, len(pt), 2 * lba, 2 * max(ldc, 1e-12)], f32)
    has_dcw = dc_weight is not None
    dcw = np.ascontiguousarray(np.asarray(dc_weight)[order], f32) if has_dcw else np.ones(1, f32)
    args = (np.ascontiguousarray(R, f32), np.ascontiguousarray(t, f32), k, w, starts,
            np.ascontiguousarray(np.asarray(fr)[order], np.int64), np.ascontiguousarray(np.asarray(uv)[order], f32),
            np.ascontiguousarray(np.asarray(depth)[order], f32), dcw, has_dcw, bool(offsets), bool(log_dc), int(iters))
    X = np.zeros((n_points, 3), f32)
    # the points in parts of equal observation counts on parallel threads: each point's fit is its own
    in_parts(lambda lo, hi: _fit_points(*args, lo, hi, X), part_bounds(starts, worker_threads(), MIN_PART_OBS))
    return X
