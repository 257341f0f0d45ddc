import numpy as np
import pytest

from trackingworld.optim.ratio_field import (
    LogField,
    _bilinear,
    _block_tridiagonal_solve,
    _difference_operator,
    fit_log_field,
    fit_log_fields,
)

H, W = 240, 320


def warp(uv):
    """A smooth log-depth warp like a monocular prior's: two low-frequency waves, a few percent."""
    x, y = uv[:, 0] / W, uv[:, 1] / W
    return 0.05 * np.cos(2 * np.pi * (0.8 * x + 0.4 * y) + 1.0) + 0.03 * np.cos(2 * np.pi * (0.3 * x - 0.9 * y))


def test_the_field_recovers_a_smooth_warp_inside_a_hole_despite_outliers():
    """Samples around an empty rectangle (where a moving object would be), with noise and 10% outliers: the
    field inside the hole is far closer to the warp than the samples' median, and the outliers do not pull it."""
    rng = np.random.default_rng(0)
    uv = rng.uniform([0, 0], [W - 1, H - 1], (6000, 2))
    hole = (np.abs(uv[:, 0] - 160) < 40) & (np.abs(uv[:, 1] - 120) < 30)
    uv = uv[~hole]
    val = warp(uv) + 0.005 * rng.standard_normal(len(uv)) + 0.7  # 0.7: the frame's overall log scale
    bad = rng.random(len(uv)) < 0.1
    val[bad] += 0.3
    f = fit_log_field(uv, val, (H, W))
    q = np.stack(np.meshgrid(np.arange(125, 196), np.arange(95, 146)), -1).reshape(-1, 2).astype(float)
    err_field = np.abs(f(q) - (warp(q) + 0.7))
    err_median = np.abs(np.median(val) - (warp(q) + 0.7))
    assert np.median(err_field) < 0.01
    assert np.median(err_field) < 0.3 * np.median(err_median)
    everywhere = rng.uniform([0, 0], [W - 1, H - 1], (2000, 2))
    assert np.median(np.abs(f(everywhere) - (warp(everywhere) + 0.7))) < 0.01


def test_the_field_of_no_samples_is_zero_and_float32_pixels_at_the_border_are_inside():
    f = fit_log_field(np.zeros((0, 2)), np.zeros(0), (H, W))
    assert np.all(f(np.array([[0.0, 0.0], [W - 1, H - 1]])) == 0)
    uv = np.array([[W - 1, H - 1], [0, 0], [W / 2, H / 2]], np.float32)  # the corner: a float32 rounding case
    g = fit_log_field(uv, np.array([0.1, 0.1, 0.1]), (H, W), cells=(2, 2))
    assert np.allclose(g(uv), 0.1)


def test_fields_fitted_together_see_under_a_moving_hole_through_their_neighbours_in_time():
    """A warp drifting slowly over 12 frames, each frame with its own scale; a hole (a moving object) slides
    across the image. With the temporal coupling the field inside each frame's hole is closer to the warp than
    the per-frame fit's, each frame keeps its own level, and weight 0 is the per-frame fit exactly."""
    from trackingworld.optim.ratio_field import fit_log_fields

    rng = np.random.default_rng(3)
    T = 12
    samples, holes, truth = [], [], []
    for t in range(T):
        uv = rng.uniform([0, 0], [W - 1, H - 1], (1500, 2))
        cx = 60 + 17 * t
        hole = (np.abs(uv[:, 0] - cx) < 55) & (np.abs(uv[:, 1] - 120) < 60)
        level = 0.1 * rng.standard_normal()  # the prior's per-frame scale
        f_t = lambda q, t=t, level=level: warp(q + np.array([2.0 * t, 0.0])) + level  # noqa: E731
        uv = uv[~hole]
        samples.append((uv, f_t(uv) + 0.005 * rng.standard_normal(len(uv))))
        q = np.stack(np.meshgrid(np.arange(cx - 45, cx + 46, 5), np.arange(70, 171, 5)), -1).reshape(-1, 2)
        holes.append(q.astype(float))
        truth.append(f_t(q.astype(float)))
    alone = fit_log_fields(samples, (H, W), temporal=0.0)
    together = fit_log_fields(samples, (H, W), temporal=3.0)
    err_alone = np.mean([np.median(np.abs(f(q) - g)) for f, q, g in zip(alone, holes, truth, strict=True)])
    err_together = np.mean([np.median(np.abs(f(q) - g)) for f, q, g in zip(together, holes, truth, strict=True)])
    assert err_together < 0.7 * err_alone
    for f, (uv, val) in zip(together, samples, strict=True):  # each frame's level is its own
        assert abs(np.median(f(uv) - val)) < 0.01
    single = fit_log_field(*samples[4], (H, W))
    assert np.allclose(alone[4].values, single.values) and alone[4].offset == single.offset
    assert fit_log_fields([None, samples[0], None], (H, W), temporal=3.0)[0] is None


def test_block_tridiagonal_solve_matches_a_dense_solve():
    from trackingworld.optim.ratio_field import _block_tridiagonal_solve

    rng = np.random.default_rng(0)
    T, m = 5, 4
    off = rng.normal(size=(m, m))
    off = -(off @ off.T) * 0.1
    diag = np.stack([np.eye(m) * 5 + 0.1 * (a @ a.T) for a in rng.normal(size=(T, m, m))])
    rhs = rng.normal(size=(T, m))
    A = np.zeros((T * m, T * m))
    for t in range(T):
        A[t * m:(t + 1) * m, t * m:(t + 1) * m] = diag[t]
        if t:
            A[t * m:(t + 1) * m, (t - 1) * m:t * m] = off
            A[(t - 1) * m:t * m, t * m:(t + 1) * m] = off
    assert np.allclose(_block_tridiagonal_solve(diag, off, rhs).ravel(), np.linalg.solve(A, rhs.ravel()))


def test_the_thin_plate_penalty_leaves_planes_free_and_continues_the_slopes_into_a_hole():
    """Order 2 (the thin-plate energy of second differences): constants and planes cost nothing, curvature does;
    across a large hole its field follows the warp more closely than the first differences' at the same weight."""
    gy, gx = np.mgrid[0:7, 0:9].astype(float)
    for order, free, costly in ((1, [np.ones(63)], [gx.ravel(), gx.ravel() ** 2]),
                                (2, [np.ones(63), (gx + 2 * gy).ravel()], [(gx ** 2).ravel(), (gx * gy).ravel()])):
        A = _difference_operator((8, 6), order)
        assert all(abs(f @ A @ f) < 1e-9 for f in free) and all(f @ A @ f > 1 for f in costly)
    with pytest.raises(ValueError, match="order: 3"):
        _difference_operator((8, 6), 3)
    rng = np.random.default_rng(0)
    uv = rng.uniform([0, 0], [W - 1, H - 1], (6000, 2))
    uv = uv[~((np.abs(uv[:, 0] - 160) < 80) & (np.abs(uv[:, 1] - 120) < 60))]
    val = warp(uv) + 0.005 * rng.standard_normal(len(uv))
    q = np.stack(np.meshgrid(np.arange(85, 236), np.arange(65, 176)), -1).reshape(-1, 2).astype(float)
    err = {o: np.median(np.abs(fit_log_fields([(uv, val)], (H, W), (8, 6), 0.001, order=o)[0](q) - warp(q)))
           for o in (1, 2)}
    assert err[2] < 0.7 * err[1]


def _fields_numpy(samples, shape, cells=(8, 6), smooth=0.01, temporal=0.0, scale=0.02, iters=4, order=1):
    """The numpy formulation the compiled fit replaced (stop 72): each frame's normal equations from one bincount
    of its samples' node pairs, the Cauchy weights from numpy's residuals. Node values [T,m] (NaN rows: None)."""
    T, m = len(samples), (cells[0] + 1) * (cells[1] + 1)
    LtL = _difference_operator(cells, order)
    frames, offsets = [], np.zeros(T)
    for t, s in enumerate(samples):
        if s is None or not len(s[1]):
            frames.append(None)
            continue
        values = np.asarray(s[1], np.float64)
        offsets[t] = float(np.median(values))
        idx, w = _bilinear(s[0], shape, cells)
        rows = np.repeat(idx, 4, axis=1).ravel() * m + np.tile(idx, (1, 4)).ravel()
        frames.append((idx, w, values - offsets[t], rows, smooth * len(values) / m * LtL + 1e-9 * np.eye(m)))
    counts = [len(f[2]) for f in frames if f is not None]
    tau = temporal * float(np.mean(counts)) / m * (np.eye(m) - 1.0 / m) if temporal > 0 else None
    robust = [None if f is None else np.ones(len(f[2])) for f in frames]
    for _ in range(iters):
        diag, rhs = np.tile(1e-9 * np.eye(m), (T, 1, 1)), np.zeros((T, m))
        for t, f in enumerate(frames):
            if f is not None:
                idx, w, y, rows, pen = f
                wr = w * robust[t][:, None]
                diag[t] = np.bincount(rows, (wr[:, :, None] * w[:, None, :]).ravel(), m * m).reshape(m, m) + pen
                rhs[t] = np.bincount(idx.ravel(), (wr * y[:, None]).ravel(), m)
        if tau is None:
            x = np.linalg.solve(diag, rhs[..., None])[..., 0]
        else:
            diag += ((np.arange(T) > 0).astype(int) + (np.arange(T) < T - 1))[:, None, None] * tau
            x = _block_tridiagonal_solve(diag, -tau, rhs)
        for t, f in enumerate(frames):
            if f is not None:
                robust[t] = 1.0 / (1.0 + (((x[t][f[0]] * f[1]).sum(1) - f[2]) / scale) ** 2)
    return np.where(np.array([f is None for f in frames])[:, None], np.nan, x), offsets


@pytest.mark.parametrize("temporal,order", [(0.0, 1), (1.0, 1), (1.0, 2)])
def test_the_compiled_fields_are_the_numpy_formulations_to_the_bit(temporal, order):
    rng = np.random.default_rng(5)
    samples = []
    for n in (3000, 0, 800, 5000, 60):
        uv = rng.uniform([-2, -2], [W + 1, H + 1], (n, 2)).astype(np.float32)  # float32 pixels, a few outside
        samples.append((uv, warp(uv) + 0.01 * rng.standard_normal(n) + (rng.random(n) < 0.1) * 0.4))
    samples.append(None)
    ref, offsets = _fields_numpy(samples, (H, W), temporal=temporal, order=order)
    got = fit_log_fields(samples, (H, W), temporal=temporal, order=order)
    for t, f in enumerate(got):
        assert (f is None) == np.isnan(ref[t]).all()
        if f is not None:
            assert np.array_equal(f.values, ref[t]) and f.offset == offsets[t]
    q = np.r_[rng.uniform([-5, -5], [W + 5, H + 5], (4000, 2)), [[0, 0], [W - 1, H - 1], [W - 1, 0]]]
    f = got[0]
    idx, w = _bilinear(q, (H, W), f.cells)
    assert np.array_equal(f(q), (f.values[idx] * w).sum(1) + f.offset)  # the field at pixels: numpy's sums
    assert np.array_equal(f(q.astype(np.float32)), LogField(f.values, f.offset, f.shape, f.cells)(
        q.astype(np.float32).astype(np.float64)))
