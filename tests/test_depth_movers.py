"""The depth-discrepancy test of movers the masks missed (optim.depth_movers) and its glue in the pipeline."""

import numpy as np

from trackingworld.geometry import intrinsics_matrix, invert_pose, project, transform, unproject
from trackingworld.optim.depth_movers import (
    BilateralWindows,
    depth_movers,
    depth_movers_at,
    less_fields,
    local_majority,
    log_depth_ratios,
)
from trackingworld.pipeline import fields as prior_fields

K = intrinsics_matrix(300.0, 300.0, 160.0, 120.0)


def test_local_majority_is_the_fraction_flagged_in_the_window_of_cells(rng):
    T, M, cell, win = 3, 4000, 4.0, 20.0
    frame = rng.integers(0, T, M)
    uv = rng.uniform([0, 0], [319.9, 239.9], (M, 2))
    flag = rng.random(M) < 0.3
    got = local_majority(frame, uv, flag, T, (240, 320), win, cell)
    c = np.floor(uv / cell).astype(int)
    half = int(round(win / cell)) // 2  # a 5 x 5 cell window
    for i in rng.choice(M, 200, replace=False):  # by brute force
        near = (frame == frame[i]) & (np.abs(c - c[i]) <= half).all(1)
        assert np.isclose(got[i], flag[near].mean())


def test_the_bilateral_window_counts_the_cells_window_in_the_bins_beside_its_own(rng):
    T, M, cell, win, width = 3, 5000, 4.0, 20.0, 0.1
    frame = rng.integers(0, T, M)
    uv = rng.uniform([0, 0], [319.9, 239.9], (M, 2))
    log_d = rng.uniform(0.0, 1.5, M)
    flags = [rng.random(M) < 0.3, rng.random(M) < 0.6]
    got = BilateralWindows.build(frame, uv, log_d, T, (240, 320), win, width, cell).fractions(flags)
    c, b = np.floor(uv / cell).astype(int), np.floor(log_d / width).astype(int)
    for i in rng.choice(M, 200, replace=False):  # by brute force
        near = (frame == frame[i]) & (np.abs(c - c[i]) <= 2).all(1) & (np.abs(b - b[i]) <= 1)
        for g, f in zip(got, flags, strict=True):
            assert g[i] == f[near].sum() / near.sum()  # counts of 0/1 flags: exact


def test_the_bilateral_window_finds_a_mover_too_small_for_the_square(rng):
    """A 12 x 12 px object 2 m in front of a wall 6 m away, every observation 15% off the prior; the wall's
    observations right. In the 20 px square the object is a third of the window at most and loses the vote; among
    the observations of its own depth it wins it. The wall's isolated outliers are flagged by neither."""
    T, n = 4, 6000
    uv = rng.uniform([0, 0], [319, 239], (n, 2))
    obj = (np.abs(uv[:, 0] - 150) < 6) & (np.abs(uv[:, 1] - 100) < 6)
    track, frame = np.repeat(np.arange(n), T), np.tile(np.arange(T), n)
    log_d = np.log(np.where(obj, 4.0, 6.0))[track] + rng.normal(0, 0.01, n * T)
    e = rng.normal(0, 0.015, n * T) + np.where(obj[track], 0.15, 0.0)
    out = rng.random(n * T) < 0.05
    e[out] += 0.2
    xy = uv[track] + rng.normal(0, 0.3, (n * T, 2))
    square, = depth_movers_at(track, frame, xy, e, n, T, (240, 320), [0.05], 20.0)
    windows = BilateralWindows.build(frame, xy, log_d, T, (240, 320), 20.0, 0.1)
    bilateral, = depth_movers_at(track, frame, xy, e, n, T, (240, 320), [0.05], 20.0, windows)
    assert square[obj].mean() < 0.5
    assert bilateral[obj].mean() > 0.9
    assert bilateral[~obj].mean() < 0.01
    # with a factor: the square's majority at the threshold or the depth's at twice it; 15% off passes 2 x 5%
    either, = depth_movers_at(track, frame, xy, e, n, T, (240, 320), [0.05], 20.0, windows, 2.0)
    assert either[obj].mean() > 0.9 and either[~obj].mean() < 0.01
    # 7% off: the depth's majority at 5% holds, at 10% it does not, and the square's is lost
    e_small = e - np.where(obj[track], 0.08, 0.0)
    assert depth_movers_at(track, frame, xy, e_small, n, T, (240, 320), [0.05], 20.0, windows)[0][obj].mean() > 0.9
    assert depth_movers_at(track, frame, xy, e_small, n, T, (240, 320), [0.05], 20.0, windows, 2.0)[0][obj].mean() < 0.1


def _patch_scene(rng, e_mover: float):
    """One frame set of scattered observations: a 60 x 40 px patch of 'mover' tracks whose discrepancy is
    ``e_mover`` (plus noise), the rest static with noise and 5% isolated outliers of +-0.2."""
    T, N = 4, 6000
    uv = rng.uniform([0, 0], [319, 239], (N, 2))
    mover = (uv[:, 0] > 100) & (uv[:, 0] < 160) & (uv[:, 1] > 80) & (uv[:, 1] < 120)
    track, frame = np.repeat(np.arange(N), T), np.tile(np.arange(T), N)
    e = rng.normal(0, 0.015, N * T) + np.where(mover[track], e_mover, 0.0)
    out = rng.random(N * T) < 0.05
    e[out] += rng.choice([-0.2, 0.2], out.sum())
    return track, frame, uv[track] + rng.normal(0, 0.5, (N * T, 2)), e, mover


def test_depth_movers_flag_a_coherent_region_and_not_scattered_outliers(rng):
    for e_mover in (0.1, -0.1):  # farther or nearer than the prior
        track, frame, uv, e, mover = _patch_scene(rng, e_mover)
        got = depth_movers(track, frame, uv, e, len(mover), 4, (240, 320), thresh=0.05, window_px=20)
        # the patch's border tracks see half static neighbours: most, not all, of it is flagged
        assert got[mover].mean() > 0.8
        assert got[~mover].mean() < 0.01
    assert not depth_movers(track, frame, uv, np.zeros_like(e), len(mover), 4, (240, 320)).any()
    assert not depth_movers(*(np.zeros(0, int),) * 2, np.zeros((0, 2)), np.zeros(0), 5, 4, (240, 320)).any()


def _fitted_patch(rng, T: int, N: int, half_h: float):
    """N static points 4-8 m away seen by a camera sliding 5 cm a frame over T frames, whose fitted static points
    (what the bundle adjustment returns) are right except in a patch 60 px wide and 2 half_h px high around (200,
    100) px, 12% too far (a mover along the epipolar lines): (c2w [T,4,4], patch [N] bool, fitted xyz [N,T,3],
    true pixels uv [N,T,2], true camera depth [N,T])."""
    c2w = np.tile(np.eye(4), (T, 1, 1))
    c2w[:, 0, 3] = 0.05 * np.arange(T)
    uv0 = rng.uniform([0, 0], [319, 239], (N, 2))
    z = rng.uniform(4, 8, N)
    patch = (np.abs(uv0[:, 0] - 200) < 30) & (np.abs(uv0[:, 1] - 100) < half_h)
    X_true = unproject(uv0, z, K)
    X_fit = unproject(uv0, z * np.where(patch, 1.12, 1.0), K)  # frame 0's camera = world
    uv, z_cam = project(transform(invert_pose(c2w)[None], np.repeat(X_true[:, None], T, 1)), K)
    return c2w, patch, np.repeat(X_fit[:, None], T, 1), uv, z_cam


def test_depth_discrepancy_removes_the_priors_smooth_warp_and_finds_the_epipolar_mover(rng):
    """Static points and a patch whose fitted static points are 12% too far (what a mover along the epipolar
    lines gets from the bundle adjustment), under a prior off by a per-frame scale and a smooth warp of +-8%: with
    each frame's field removed, the patch is found and no static region is; the raw log ratio without the field
    flags static regions."""
    T, N = 5, 5000
    c2w, patch, xyz, uv, z_cam = _fitted_patch(rng, T, N, 25)
    x, y = uv[..., 0] / 320, uv[..., 1] / 320
    t = np.arange(T)[None]
    warp = 0.08 * np.cos(2 * np.pi * (0.6 * x - 0.4 * y) + 0.4 * t) + 0.1 * rng.standard_normal(T)[None]
    D = z_cam * np.exp(warp + rng.normal(0, 0.01, z_cam.shape))
    vis = np.ones((N, T), bool)
    static = np.arange(N)
    k, fr, e_raw = log_depth_ratios(static, vis[static], xyz, D, c2w)
    assert len(k) == N * T and (np.diff(fr) >= 0).all()
    refs = prior_fields.reference_ratios(static, uv, vis, xyz, D, c2w)
    got = np.zeros(N, bool)
    for _ in range(2):  # as the pipeline: the fields again without the movers of the first round
        fields = prior_fields.static_fields(static[~got], uv, vis, xyz, D, c2w, (240, 320), (8, 6), 0.01, refs=refs)
        keep, e = less_fields(uv[static[k], fr], fr, e_raw, fields)
        assert keep.all()
        got = depth_movers(k, fr, uv[static[k], fr], e, N, T, (240, 320), 0.05, 20)
    assert got[patch].mean() > 0.8 and got[~patch].mean() < 0.01
    # without the fields (the raw log ratio) static regions are flagged
    raw = depth_movers(k, fr, uv[static[k], fr], e_raw, N, T, (240, 320), 0.05, 20)
    assert raw[~patch].mean() > 0.05


def test_suspects_left_out_of_the_fields_unhide_a_large_mover(rng):
    """A patch about a field cell across whose fitted points are 12% too far: fitted among the static tracks, it
    pulls its frames' fields toward itself and hides most of itself; the rounds that leave the suspects (the
    tracks over half the threshold) out of the fields find it, and still no static region."""
    from dataclasses import replace

    from trackingworld.config import OptimConfig

    T, N = 5, 6000
    c2w, patch, xyz, uv, z_cam = _fitted_patch(rng, T, N, 30)
    D = z_cam * np.exp(0.1 * rng.standard_normal(T)[None] + rng.normal(0, 0.01, z_cam.shape))
    vis = np.ones((N, T), bool)
    static = np.arange(N)
    cfg = replace(OptimConfig(), test_frames=0, depth_mover_log=0.05)
    found = {}
    for rounds, suspect in ((2, 1.0), (3, 0.5)):
        c = replace(cfg, depth_mover_rounds=rounds, depth_mover_suspect=suspect)
        found[rounds, suspect] = prior_fields.depth_mover_test(static, static, uv, vis, xyz, D, c2w, (240, 320), c)[0]
    assert found[3, 0.5][patch].mean() > 0.8 and found[3, 0.5][~patch].mean() < 0.01
    assert found[2, 1.0][patch].mean() < found[3, 0.5][patch].mean() - 0.2


def test_blur_tolerant_forgives_a_blurred_depth_edge_and_not_a_mover(rng):
    """A prior with a depth step (4 m | 8 m at x = 160) blurred over 2 px: the observations at the edge whose fitted
    depth is their own side's true depth read a large discrepancy at their pixel and none within 2 px; a patch
    fitted 10% too far keeps its 10%."""
    import cv2

    from trackingworld.optim.depth_movers import blur_tolerant, prior_spread

    T, H, W = 2, 60, 320
    truth = np.where(np.arange(W)[None] < 160, 4.0, 8.0) * np.ones((T, H, W))
    prior = np.stack([cv2.GaussianBlur(d.astype(np.float32), (0, 0), 1.0) for d in truth])
    uv = np.stack([rng.uniform(150, 170, 400), rng.uniform(5, 55, 400)], 1)
    t = np.sort(rng.integers(0, T, 400))
    px = np.rint(uv).astype(int)
    z = truth[t, px[:, 1], px[:, 0]] * np.where(uv[:, 0] > 165, 1.1, 1.0)  # the far side's right part: a mover
    e = np.log(z / prior[t, px[:, 1], px[:, 0]])
    edge = np.abs(px[:, 0] - 159.5) < 2
    assert np.abs(e[edge]).max() > 0.2  # the blur, read at the pixel
    far, near = prior_spread(t, uv, prior, 2)
    assert (far >= 0).all() and (near <= 0).all()
    got = blur_tolerant(e, far, near)
    assert np.abs(got[edge]).max() < 0.01  # (the Gaussian's tail beyond 2 px)
    mover = uv[:, 0] > 166
    assert np.allclose(got[mover], np.log(1.1), atol=1e-3)
    # a point on the near side of the edge fitted 20% too far (a mover's rim the bundle adjustment misplaced) lies
    # between the two sides' depths: not forgiven, though the far side's depth is within reach
    rim = edge & (px[:, 0] <= 159)
    e_rim = np.log(truth[t, px[:, 1], px[:, 0]] * 1.2 / prior[t, px[:, 1], px[:, 0]])
    assert rim.any() and (np.abs(blur_tolerant(e_rim, far, near)[rim]) > 0.05).all()
    within = (e_rim <= far) & (e_rim >= near)  # a rule that forgave the whole range would call these 0
    assert within[rim].all()
    assert np.array_equal(blur_tolerant(e, *prior_spread(t, uv, prior, 0)), e)  # radius 0: the value at the pixel


def test_threshold_in_mads_spares_a_noisy_priors_static_regions_and_leaves_a_clean_one_alone():
    """Static points and a patch fitted 25% too far, under a prior with a per-frame scale, 1% pixel noise and a
    smooth residual of its own that the fields do not follow (blurred noise, 8 px). Clean (no residual): the
    threshold in MADs stays at the fixed one and the result is the same. With a 6% residual the fixed threshold
    flags static regions; 6 MADs does not, and still finds a good part of the patch (47% here)."""
    from dataclasses import replace

    import cv2

    from trackingworld.config import OptimConfig

    rng = np.random.default_rng(0)
    T, N = 5, 6000
    c2w = np.tile(np.eye(4), (T, 1, 1))
    c2w[:, 0, 3] = 0.05 * np.arange(T)
    uv0 = rng.uniform([0, 0], [319, 239], (N, 2))
    z = rng.uniform(4, 8, N)
    patch = (np.abs(uv0[:, 0] - 200) < 30) & (np.abs(uv0[:, 1] - 100) < 25)
    xyz = np.repeat(unproject(uv0, z * np.where(patch, 1.25, 1.0), K)[:, None], T, 1)
    uv, z_cam = project(transform(invert_pose(c2w)[None], np.repeat(unproject(uv0, z, K)[:, None], T, 1)), K)
    x, y = np.clip(np.round(uv[..., 0]).astype(int), 0, 319), np.clip(np.round(uv[..., 1]).astype(int), 0, 239)
    vis, static = np.ones((N, T), bool), np.arange(N)
    got = {}
    for amp in (0.0, 0.06):
        residual = np.stack([cv2.GaussianBlur(rng.standard_normal((240, 320)).astype(np.float32), (0, 0), 8)
                             for _ in range(T)])
        residual *= amp / residual.std()
        D = z_cam * np.exp(0.1 * rng.standard_normal(T)[None] + residual[np.arange(T)[None], y, x]
                           + rng.normal(0, 0.01, z_cam.shape))
        for mad in (0.0, 6.0):
            cfg = replace(OptimConfig(), test_frames=0, depth_mover_log=0.05, depth_mover_mad=mad)
            got[amp, mad] = prior_fields.depth_mover_test(static, static, uv, vis, xyz, D, c2w, (240, 320), cfg)[0]
    assert np.array_equal(got[0.0, 0.0], got[0.0, 6.0]) and got[0.0, 0.0][patch].mean() > 0.8
    assert got[0.06, 0.0][~patch].mean() > 0.02
    assert got[0.06, 6.0][~patch].mean() < 0.005 and got[0.06, 6.0][patch].mean() > 0.3


def test_the_estimated_range_forgives_a_2_px_blur_that_1_px_does_not(rng):
    """A prior with depth steps (a box at 4 m on a wall at 8 m) blurred by 2 px, observations fitted at their own
    side's true depth: measured to the prior's extremes within 1 px, the points 2-3 px from an edge still read the
    other side's blur (over the test's 3%); within the range estimated from the prior (2 px) they do not. A patch
    fitted 10% too far keeps its 10% either way."""
    import cv2

    from trackingworld.optim.depth_movers import blur_tolerant, prior_spread

    T, H, W = 2, 120, 160
    truth = np.full((T, H, W), 8.0)
    truth[:, 30:90, 40:120] = 4.0
    prior = np.stack([cv2.GaussianBlur(d.astype(np.float32), (0, 0), 2.0) for d in truth])
    reach = prior_fields.mover_range_px(None, prior)
    assert reach == 2
    uv = rng.uniform([5, 5], [W - 6, H - 6], (4000, 2))
    t = np.sort(rng.integers(0, T, 4000))
    px = np.rint(uv).astype(int)
    mover = (uv[:, 0] > 130) & (uv[:, 1] > 95)  # on the wall, away from the box
    z = truth[t, px[:, 1], px[:, 0]] * np.where(mover, 1.1, 1.0)
    e = np.log(z / prior[t, px[:, 1], px[:, 0]])
    box_x, box_y = np.abs(px[:, 0] - 79.5) - 40, np.abs(px[:, 1] - 59.5) - 30  # > 0 outside the box
    dist = np.where((box_x > 0) | (box_y > 0), np.hypot(np.maximum(box_x, 0), np.maximum(box_y, 0)),
                    -np.minimum(-box_x, -box_y))  # signed distance to the box's edge (inside < 0)
    band = (np.abs(dist) >= 2) & (np.abs(dist) <= 3)
    wrong = {r: np.abs(blur_tolerant(e, *prior_spread(t, uv, prior, r))) > 0.03 for r in (1, reach)}
    assert wrong[1][band].mean() > 0.3
    assert wrong[reach][band].mean() < 0.05
    for r in (1, reach):
        assert np.allclose(blur_tolerant(e, *prior_spread(t, uv, prior, r))[mover], np.log(1.1), atol=1e-3)


def test_the_compiled_nearest_end_is_numpys_to_the_bit_with_ties_and_nans():
    from trackingworld.optim.depth_movers import blur_tolerant, blur_tolerant_numpy

    rng = np.random.default_rng(5)
    M = 20000
    e = rng.normal(0, 0.05, M)
    far = np.abs(rng.normal(0, 0.05, M))
    near = -np.abs(rng.normal(0, 0.05, M))
    e[:100] = 0.5 * far[:100]  # a tie between the pixel's value and the far end: the first (the pixel) wins
    near[100:200] = far[100:200] = e[100:200]  # both ends at e
    e[200:210] = np.nan
    far[210:220] = np.nan  # argmin takes the first NaN of the distances
    near[220:230] = np.nan
    got = blur_tolerant(e, far, near)
    ref = blur_tolerant_numpy(e, far, near)
    np.testing.assert_array_equal(got, ref)
    assert np.isnan(got[200:230]).all() and np.isfinite(got[230:]).all()
    assert np.array_equal(got[:100], e[:100]) and (got[100:200] == 0).all()
    e32 = e[230:].astype(np.float32)  # another dtype: the numpy code
    np.testing.assert_array_equal(blur_tolerant(e32, far[230:], near[230:]), blur_tolerant_numpy(e32, far[230:],
                                                                                                   near[230:]))
