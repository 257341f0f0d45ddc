"""Compile the CPU kernels once, at install time (``make setup`` runs ``python -m trackingworld.optim.warmup``).

numba compiles :mod:`trackingworld.optim.point_fit`, :mod:`trackingworld.optim.ba_blocks`,
:mod:`trackingworld.optim.static_fit`, the spread frames of :mod:`trackingworld.optim.static_tests`, the
weighted mean and the thinning of :mod:`trackingworld.optim.densify`,
the nearest ends and the windows of the same depth of :mod:`trackingworld.optim.depth_movers`,
the projections of :mod:`trackingworld.optim.photo_static` and the fields of :mod:`trackingworld.optim.ratio_field`
on their first call and caches the machine code beside
the package; without this step the first run on a machine pays that compile (about 25 s on a 2-core CPU) in the
middle of its optimisation. Each kernel is called here once on a tiny problem, with the argument types the
pipeline calls it with.
"""

from __future__ import annotations

import sys
import time

import numpy as np


def warm() -> float:
    """Call every compiled kernel once (compiling it, or loading it from numba's cache). Returns the seconds it
    took."""
    from trackingworld.optim import (
        ba_blocks,
        densify,
        depth_movers,
        photo_static,
        point_fit,
        ratio_field,
        static_fit,
        static_tests,
    )

    t0 = time.perf_counter()
    rng = np.random.default_rng(0)
    T, N = 4, 6
    R = np.tile(np.eye(3), (T, 1, 1))
    t = np.c_[0.1 * rng.standard_normal((T, 2)), np.full(T, 3.0)]
    K = np.array([[300.0, 0.0, 160.0], [0.0, 300.0, 120.0], [0.0, 0.0, 1.0]])
    uv = (160 + 20 * rng.standard_normal((N, T, 2))).astype(np.float32)
    depth = np.full((N, T), 3.0)
    vis = np.ones((N, T), bool)
    weights = (1.0, 1.0, 5.0)
    for pixels in (uv, uv.astype(np.float64)):  # the rigid step's float32 pixels, and float64
        point_fit.fit_and_score(R, t, K, pixels, depth, vis, weights, rows=np.arange(N), frames=np.arange(T))
    pt, fr = np.nonzero(vis)
    X = rng.standard_normal((N, 3))
    blocks = ba_blocks.linearize(R, t, X, pt, fr, uv[pt, fr], depth[pt, fr], K, weights)
    ba_blocks.cost(R, t, X, pt, fr, uv[pt, fr], depth[pt, fr], K, weights)
    free = np.ones(T, bool)
    free[0] = False
    for how in ("blas", "pairs"):
        ba_blocks.schur_step(*blocks, pt, fr, 1e-3, free, how)
    for dc_weight in (None, np.ones(len(pt))):  # the static tests' fits (float32), with and without depth weights
        static_fit.fit_points(R, t, pt, fr, uv[pt, fr], depth[pt, fr], K, weights, True, True, None, dc_weight, N)
    densify.propagate_ratio(uv[:, 0], depth[:, 0], np.ones(N), uv[:, 1], depth[:, 1], K)  # the IDW mean
    densify.thinned_observations(uv, vis, 4.0)  # the video depth's references
    static_tests.spread_observations(vis, 2)  # the frames the static fits and tests read
    depth_movers.blur_tolerant(np.zeros(N), np.ones(N), -np.ones(N))  # the depth-mover test's nearest ends
    windows = depth_movers.BilateralWindows.build(fr, uv[pt, fr], np.log(depth[pt, fr]), T, (240, 320), 20.0, 0.1)
    windows.fractions([np.ones(len(pt), bool)])  # its windows of the same prior depth
    fields = ratio_field.fit_log_fields([(uv[:, 0], np.zeros(N)), None], (240, 320))  # the depth fields
    fields[0](uv[:, 1])
    open_t = np.ones((240, 320), bool)
    for video_depth in (None, np.full((240, 320), 3.0, np.float32)):  # the photometric tests' projections
        photo_static._project_and_test(X, np.eye(4), K, open_t, video_depth, 0.9)
    return time.perf_counter() - t0


def main() -> int:
    print(f"[warmup] the CPU kernels compiled or loaded in {warm():.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
