"""The prior at a depth edge read from each side's own pixels (optim.edge_prior)."""

import cv2
import numpy as np

from trackingworld.optim.edge_prior import inner_prior


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
