"""Points fitted to their 2D tracks under fixed camera poses, compiled for the CPU (numba).

The rigid step tests every track it may add to a group by fitting the track as one point of the group's motion
(:func:`trackingworld.optim.rigid.place_on_motion`): :func:`trackingworld.optim.stage2.fit_points`' Gauss-Newton
steps on the stage-2 objective with the offsets eliminated (Huber kernels as IRLS weights), then the median and
80th percentile of its reprojection error and the median of its depth's log ratio to the targets. In torch each
step is some forty operations over ``[M,3,3]`` arrays of all the observations, which a CPU runs at the speed of its
memory (0.5 us per observation and step on the 2-core machine); here each point's few observations stay in cache
through all its steps. Torch has no way to fuse such a loop on a CPU without a C++ compiler at run time
(``torch.compile``), hence numba; the torch functions stay the reference and what a CUDA device runs
(``tests/test_compiled.py`` holds the two to the same results).

Conventions: ``R [F,3,3]``, ``t [F,3]`` camera-from-object (or world-to-camera) rotations and translations of the
solved frames, camera = R X + t (OpenCV axes); pixels x right / y down; depths metres along the camera's z.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from trackingworld.optim.ba_blocks import camera_constants, camera_point, f64, i64
from trackingworld.optim.parallel import in_parts, part_bounds, worker_threads

# the fewest tracks worth a thread of their own: alone, 200 tracks of 30 frames ran 1.1-1.9x faster on two
# threads (two runs), but in the rigid step (beside torch's threads) its 524 calls of 200-1,000 tracks gained
# nothing (0.82 -> 0.80 s) and its 19 of more than 1,000 took 0.88 -> 0.52 s (docs/speed.md, stop 72)
MIN_PART_ROWS = 2000


@njit(cache=True, error_model="numpy")
def _solve3(h00, h01, h02, h11, h12, h22, g0, g1, g2):
    """``H^-1 g`` for a symmetric positive definite ``H`` (its upper triangle ``h``) and ``g`` (Cholesky)."""
    l00 = math.sqrt(h00)
    l10 = h01 / l00
    l20 = h02 / l00
    l11 = math.sqrt(max(h11 - l10 * l10, 1e-300))
    l21 = (h12 - l20 * l10) / l11
    l22 = math.sqrt(max(h22 - l20 * l20 - l21 * l21, 1e-300))
    y0 = g0 / l00
    y1 = (g1 - l10 * y0) / l11
    y2 = (g2 - l20 * y0 - l21 * y1) / l22
    x2 = y2 / l22
    x1 = (y1 - l21 * x2) / l11
    x0 = (y0 - l10 * x1 - l20 * x2) / l00
    return x0, x1, x2


@njit(cache=True, error_model="numpy")
def _insertion_sort(v, n):
    """``v[:n]`` sorted in place (a track's few values: no allocation, faster than a general sort)."""
    for j in range(1, n):
        x = v[j]
        k = j - 1
        while k >= 0 and v[k] > x:
            v[k + 1] = v[k]
            k -= 1
        v[k + 1] = x


@njit(cache=True, error_model="numpy", nogil=True)
def _fit_and_score(R, t, k, uv, depth, vis, rows, px_rows, frames, weights, offsets, log_dc, iters):
    """Every point's fit and scores (see :func:`fit_and_score`; ``k`` = fx, fy, cx, cy, the kernel's focal;
    ``weights`` = lambda_ba, lambda_dc, lambda_asap; track ``i``'s depths and visibility in row ``rows[i]``, its
    pixels in row ``px_rows[i]``)."""
    fx, fy, cx, cy, kf = k[0], k[1], k[2], k[3], k[4]
    lba, ldc, lasap = weights[0], weights[1], weights[2]
    n, F = len(rows), len(frames)
    P = np.zeros((n, 3))
    q = np.full((n, 2), np.inf)
    dz = np.full(n, np.nan)
    obs = np.empty(F, np.int64)  # a track's solved frames it is seen in (indices into ``frames``)
    e = np.empty(F)
    lr = np.empty(F)
    ld = np.empty(F)  # log of each observation's depth target (floored at 1 mm)
    for i in range(n):
        row = rows[i]
        pr = px_rows[i]
        cnt = 0
        for j in range(F):
            if vis[row, frames[j]]:
                obs[cnt] = j
                ld[cnt] = math.log(max(depth[row, frames[j]], 1e-3))
                cnt += 1
        if cnt == 0:
            continue
        # the mean of the back-projections at the target depths (stage2.init_points)
        x0 = x1 = x2 = 0.0
        for o in range(cnt):
            f = obs[o]
            c = frames[f]
            d = depth[row, c]
            c0 = (uv[pr, c, 0] - cx) / fx * d - t[f, 0]
            c1 = (uv[pr, c, 1] - cy) / fy * d - t[f, 1]
            c2 = d - t[f, 2]
            x0 += R[f, 0, 0] * c0 + R[f, 1, 0] * c1 + R[f, 2, 0] * c2
            x1 += R[f, 0, 1] * c0 + R[f, 1, 1] * c1 + R[f, 2, 1] * c2
            x2 += R[f, 0, 2] * c0 + R[f, 1, 2] * c1 + R[f, 2, 2] * c2
        x0 /= cnt
        x1 /= cnt
        x2 /= cnt
        # Gauss-Newton with IRLS weights (stage2._linearize, points_only). Torch's steps divide every weight by the
        # problem's observation count, which scales H and g alike and leaves the step as it is: left out here.
        for _ in range(iters):
            h00 = h01 = h02 = h11 = h12 = h22 = g0 = g1 = g2 = 0.0
            for o in range(cnt):
                f = obs[o]
                c = frames[f]
                y0, y1, y2 = camera_point(R, t, f, x0, x1, x2)
                z = max(y2, 1e-3)
                iz = 1.0 / z
                pu = y0 * iz
                pv = y1 * iz
                r0 = fx * pu + cx - uv[pr, c, 0]
                r1 = fy * pv + cy - uv[pr, c, 1]
                if log_dc:
                    r2 = math.log(z) - ld[o]
                    ids = iz
                    ds = z
                else:
                    r2 = y2 - depth[row, c]
                    ids = 1.0
                    ds = 1.0
                w0 = lba
                w2 = ldc
                if offsets:  # the Huber kernels' IRLS weights, thresholds from the eliminated offsets
                    w0 *= min(lasap * z / (2 * lba * kf) / max(math.sqrt(r0 * r0 + r1 * r1), 1e-12), 1.0)
                    w2 *= min(lasap * ds / (2 * max(ldc, 1e-12)) / max(abs(r2), 1e-12), 1.0)
                # rows of d residual / d X: the projection's and the depth's Jacobians times R
                a00 = fx * iz * (R[f, 0, 0] - pu * R[f, 2, 0])
                a01 = fx * iz * (R[f, 0, 1] - pu * R[f, 2, 1])
                a02 = fx * iz * (R[f, 0, 2] - pu * R[f, 2, 2])
                a10 = fy * iz * (R[f, 1, 0] - pv * R[f, 2, 0])
                a11 = fy * iz * (R[f, 1, 1] - pv * R[f, 2, 1])
                a12 = fy * iz * (R[f, 1, 2] - pv * R[f, 2, 2])
                a20 = R[f, 2, 0] * ids
                a21 = R[f, 2, 1] * ids
                a22 = R[f, 2, 2] * ids
                h00 += w0 * (a00 * a00 + a10 * a10) + w2 * a20 * a20
                h01 += w0 * (a00 * a01 + a10 * a11) + w2 * a20 * a21
                h02 += w0 * (a00 * a02 + a10 * a12) + w2 * a20 * a22
                h11 += w0 * (a01 * a01 + a11 * a11) + w2 * a21 * a21
                h12 += w0 * (a01 * a02 + a11 * a12) + w2 * a21 * a22
                h22 += w0 * (a02 * a02 + a12 * a12) + w2 * a22 * a22
                g0 += w0 * (a00 * r0 + a10 * r1) + w2 * a20 * r2
                g1 += w0 * (a01 * r0 + a11 * r1) + w2 * a21 * r2
                g2 += w0 * (a02 * r0 + a12 * r1) + w2 * a22 * r2
            reg = 1e-6 * max(max(h00, h11), max(h22, 1e-30))
            s0, s1, s2 = _solve3(h00 + reg, h01, h02, h11 + reg, h12, h22 + reg, g0, g1, g2)
            x0 -= s0
            x1 -= s1
            x2 -= s2
        P[i, 0], P[i, 1], P[i, 2] = x0, x1, x2
        # the scores (rigid.place_on_motion): reprojection error quantiles, median depth log ratio
        for o in range(cnt):
            f = obs[o]
            c = frames[f]
            y0, y1, y2 = camera_point(R, t, f, x0, x1, x2)
            z = max(y2, 1e-3)
            e0 = fx * y0 / z + cx - uv[pr, c, 0]
            e1 = fy * y1 / z + cy - uv[pr, c, 1]
            e[o] = math.sqrt(e0 * e0 + e1 * e1)
            lr[o] = abs(math.log(max(y2, 1e-6) / max(depth[row, c], 1e-6)))
        _insertion_sort(e, cnt)
        _insertion_sort(lr, cnt)
        if cnt >= 3:
            q[i, 0] = e[int(math.floor(0.5 * (cnt - 1)))]
            q[i, 1] = e[int(math.floor(0.8 * (cnt - 1)))]
        dz[i] = (lr[(cnt - 1) // 2] + lr[cnt // 2]) / 2
    return P, q, dz


def fit_and_score(R: np.ndarray, t: np.ndarray, K: np.ndarray, uv: np.ndarray, depth: np.ndarray, vis: np.ndarray,
                  weights: tuple[float, float, float], offsets: bool = True, log_dc: bool = True,
                  kernel_focal: float | None = None, iters: int = 6, rows: np.ndarray | None = None,
                  frames: np.ndarray | None = None, px_rows: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tracks ``rows [n]`` (None: all) each fitted as one point under fixed poses ``R [F,3,3]``, ``t [F,3]``
    (camera = R X + t) of the frames ``frames [F]`` (None: all) from their pixels ``uv [N,T,2]`` (float32 or
    float64) and depth targets ``depth [N,T]`` (metres) where ``vis [N,T]`` sees them: ``iters`` Gauss-Newton steps of
    :func:`trackingworld.optim.stage2.fit_points` (``weights`` = the objective's lambda_ba, lambda_dc,
    lambda_asap; ``offsets``, ``log_dc`` and ``kernel_focal`` as in :class:`trackingworld.optim.stage2.BAProblem`).
    Returns (the points ``[n,3]``; the median and 80th percentile ``[n,2]`` px of their reprojection errors over
    those frames, inf for a track seen in fewer than 3; the median ``[n]`` of ``|log(camera depth / target)|``, NaN
    for a track seen in none). ``px_rows [n]``: the tracks' rows of ``uv [M,T,2]`` where they are not ``rows``
    (the rigid step reads the pipeline's pixels of every track in place, :class:`trackingworld.optim.rigid.Rows`;
    None: ``rows``)."""
    rows = i64(np.arange(len(vis)) if rows is None else rows)
    px_rows = rows if px_rows is None else i64(px_rows)
    frames = np.arange(vis.shape[1]) if frames is None else frames
    # float32 pixels are read as they are (a second compiled signature): every sum they enter has a float64 term, so
    # the numbers are those of a float64 copy, which for the rigid step's [N,T,2] would be 16 bytes an observation
    px = np.ascontiguousarray(uv) if uv.dtype == np.float32 else f64(uv)
    args = (f64(R), f64(t), camera_constants(K, kernel_focal), px, f64(depth), np.ascontiguousarray(vis, np.bool_))
    rest = (i64(frames), f64(weights), bool(offsets), bool(log_dc), int(iters))
    # the tracks in parts on parallel threads: each one's fit is its own
    parts = in_parts(lambda lo, hi: _fit_and_score(*args, rows[lo:hi], px_rows[lo:hi], *rest),
                     part_bounds(np.arange(len(rows) + 1), worker_threads(), MIN_PART_ROWS))
    if len(parts) == 1:
        return parts[0]
    return tuple(np.concatenate(a) for a in zip(*parts, strict=True))
