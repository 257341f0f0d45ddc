"""The prior at a depth edge read from each side's own pixels (optim.edge_prior)."""

import cv2
import numpy as np
import pytest

from trackingworld.optim.edge_prior import EDGE_GRAD_LOG_PER_PX, edge_blur_px, inner_prior
from trackingworld.pipeline.fields import mover_range_px


def test_a_rim_pixel_reads_its_objects_depth_not_the_blurred_background():
    H, W = 60, 80
    depth = np.full((H, W), 5.0)
    depth[20:40, 25:55] = 2.0  # a box at 2 m on a wall at 5 m
    prior = cv2.GaussianBlur(depth.astype(np.float32), (0, 0), 2.0)[None]  # the prior's edge blur
    ys, xs = np.mgrid[20:40, 25:55]
    uv = np.stack([xs.ravel(), ys.ravel()], 1)[:, None].astype(np.float32)  # the box's tracks, one frame
    vis = np.ones((len(uv), 1), bool)
    out = inner_prior(prior, uv, vis, 3.0)
    rim = (ys.ravel() == 20) | (xs.ravel() == 54)  # the box's outermost pixels
    raw = prior[0, ys.ravel(), xs.ravel()]
    new = out[0, ys.ravel(), xs.ravel()]
    assert np.median(raw[rim]) > 2.6  # the raw prior reads 30% or more too far there
    assert np.abs(new[rim] / 2.0 - 1).max() < 0.05
    inner = (ys.ravel() >= 26) & (ys.ravel() < 34) & (xs.ravel() >= 31) & (xs.ravel() < 49)
    np.testing.assert_allclose(new[inner], 2.0, rtol=0.01)
    # pixels no track covers, far from the box, keep the prior exactly
    np.testing.assert_array_equal(out[0, :5], prior[0, :5])


def test_the_wall_beside_the_box_reads_the_walls_depth_from_the_walls_tracks():
    H, W = 60, 80
    depth = np.full((H, W), 5.0)
    depth[20:40, 25:55] = 2.0
    prior = cv2.GaussianBlur(depth.astype(np.float32), (0, 0), 2.0)[None]
    ys, xs = np.mgrid[0:H, 0:W]
    wall = depth[ys, xs] == 5.0  # the static side: every wall pixel is a track
    uv = np.stack([xs[wall], ys[wall]], 1)[:, None].astype(np.float32)
    out = inner_prior(prior, uv, np.ones((len(uv), 1), bool), 1.5)
    ring = wall & (np.abs(ys - 29.5) <= 10.5) & (np.abs(xs - 39.5) <= 15.5)  # the wall's pixels touching the box
    assert np.median(prior[0][ring]) < 4.5  # the raw prior pulls them 10% or more toward the box
    assert np.abs(out[0][ring] / 5.0 - 1).max() < 0.05
    # the box's pixels beyond the Gaussian's reach (7 px) of every wall track keep the prior exactly
    np.testing.assert_array_equal(out[0, 27:33, 32:48], prior[0, 27:33, 32:48])


def test_hidden_tracks_do_not_count_and_no_track_leaves_the_prior():
    ramp = 3.0 + 0.01 * np.arange(40)[None, :] + 0.005 * np.arange(30)[:, None]  # a gently slanted wall
    prior = np.stack([ramp, ramp]).astype(np.float32)
    uv = np.array([[[10.0, 10.0], [10.0, 10.0]]], np.float32)
    out = inner_prior(prior, uv, np.array([[False, True]]), 2.0)
    np.testing.assert_array_equal(out[0], prior[0])  # hidden in frame 0: nothing changes
    near = np.zeros((30, 40), bool)
    near[8:13, 8:13] = True
    np.testing.assert_allclose(out[1][near], prior[1, 10, 10], rtol=1e-6)  # its depth spread around it
    np.testing.assert_array_equal(out[1][20:], prior[1][20:])  # and not beyond the Gaussian's reach


def _boxes_video(blur: float, frames: int = 4, noise: float = 0.0, seed: int = 0) -> np.ndarray:
    """[T,120,160] metres: boxes at 1.5-4 m on a slanted wall at 6-7 m, each frame's boxes elsewhere, blurred by a
    Gaussian of ``blur`` px, times (1 + noise) pixel noise."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(frames):
        d = 6.0 + np.linspace(0, 1, 160)[None].repeat(120, 0)
        for _ in range(6):
            x, y = rng.integers(5, 120), rng.integers(5, 85)
            d[y:y + rng.integers(15, 35), x:x + rng.integers(15, 40)] = rng.uniform(1.5, 4.0)
        d = d.astype(np.float32)
        if blur > 0:
            d = cv2.GaussianBlur(d, (0, 0), blur)
        out.append(d * (1 + noise * rng.standard_normal(d.shape)).astype(np.float32))
    return np.stack(out)


@pytest.mark.parametrize("blur", [0.0, 1.0, 2.0, 3.0])
def test_the_priors_edge_blur_is_read_from_its_depth_edges(blur):
    assert edge_blur_px(_boxes_video(blur)) == pytest.approx(blur, abs=0.3)


def test_pixel_noise_like_the_synthetic_priors_does_not_move_the_estimate():
    # 3% noise, then the whole map blurred by 1 px (the synthetic priors' noise is blurred so): edges blurred by 2
    # and then 1 px read as their combined blur
    noisy = np.stack([cv2.GaussianBlur(f, (0, 0), 1.0) for f in _boxes_video(2.0, noise=0.03)])
    assert edge_blur_px(noisy) == pytest.approx(np.hypot(2.0, 1.0), abs=0.3)


def test_a_prior_with_more_edge_pixels_than_opencvs_maps_take_is_read():
    """cv2.remap takes maps below 32767 px a side: a 640x480 prior of boxes blurred by 2 px has 56,507 pixels
    above the edge gradient, more than one row of a map holds (the weight-free prior of `dog.mp4` at 854x480 stopped
    the run there before stop 61). Its blur is read as on the small frames."""
    small = _boxes_video(2.0, frames=16)
    frame = np.block([[small[4 * i + j] for j in range(4)] for i in range(4)])  # 480x640
    tiled = np.stack([frame, frame[::-1]])
    g = cv2.magnitude(*(cv2.Sobel(np.log(tiled[0]), cv2.CV_32F, dx, 1 - dx, ksize=3, scale=1 / 8) for dx in (1, 0)))
    assert (g > EDGE_GRAD_LOG_PER_PX).sum() > 32767
    assert edge_blur_px(tiled) == pytest.approx(2.0, abs=0.3)


def test_a_prior_without_depth_edges_gives_no_estimate_and_the_range_falls_back():
    wall = np.repeat((5.0 + np.linspace(0, 1, 160))[None, None].repeat(120, 1), 3, 0).astype(np.float32)
    assert edge_blur_px(wall) is None
    assert edge_blur_px(np.ones((2, 120, 160), np.float32)) is None
    info = {}
    assert mover_range_px(None, wall, info) == 1 and info == {"prior_edge_blur_px": None}
    assert mover_range_px(None, None) == 1


def test_the_depth_discrepancy_range_follows_the_blur_unless_given():
    assert mover_range_px(None, _boxes_video(1.0)) == 1
    info = {}
    assert mover_range_px(None, _boxes_video(2.0), info) == 2
    assert info["prior_edge_blur_px"] == pytest.approx(2.0, abs=0.3)  # what the run's optim.json reports
    assert mover_range_px(None, _boxes_video(6.0)) == 4  # at most 4 px
    assert mover_range_px(0, _boxes_video(2.0)) == 0  # as given
    assert mover_range_px(3, None) == 3
