import numpy as np

from trackingworld.optim.ratio_field import fit_log_field

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
