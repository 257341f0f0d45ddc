"""The run says where the static tracks cannot place the cameras (``optim.stage1.weak_frames``)."""

import numpy as np
import pytest

from test_own_test import K, _wall_scene
from trackingworld.config import OptimConfig
from trackingworld.optim.stage1 import MIN_POSE_TRACKS, frame_ranges, pose_support_warning, weak_frames
from trackingworld.pipeline import world
from trackingworld.tracking2d.base import TrackResult


def test_frame_ranges_joins_consecutive_frames():
    assert frame_ranges(np.array([0, 1, 2, 5, 7, 8])) == "0-2, 5, 7-8"
    assert frame_ranges(np.array([4])) == "4" and frame_ranges(np.array([], int)) == ""


def test_weak_frames_are_those_with_too_few_static_tracks_seen():
    vis = np.ones((30, 6), bool)
    vis[MIN_POSE_TRACKS - 1:, 2] = False  # frame 2: one short of the minimum
    vis[:, 4] = False
    np.testing.assert_array_equal(weak_frames(vis), [2, 4])
    assert pose_support_warning(weak_frames(np.ones((30, 6), bool)), 6, 30, 40) is None
    msg = pose_support_warning(weak_frames(vis), 6, 30, 40)
    assert msg.startswith("frames 2, 4 of 6: fewer than 10 static tracks") and "the masks cover 25% of the 40" in msg
    assert "masks" not in pose_support_warning(weak_frames(vis), 6, 40, 40)  # nothing masked: the frames are bare


def test_frames_no_track_reaches_keep_the_last_pose_and_are_named():
    """Every track hidden from frame 5 on (8 frames): those frames are named, and their cameras held where stage 1
    left them, at frame 4's."""
    tr, prior, *_ = _wall_scene()
    vis = tr.visible.copy()
    vis[:, 5:] = False
    tr = TrackResult(tr.tracks, vis, tr.confidence, tr.queries)
    with pytest.warns(RuntimeWarning, match="frames 5-7 of 8: fewer than 10 static tracks seen"):
        out = world.optimise(tr, prior, np.zeros(prior.shape, bool), K, OptimConfig(verbose=False), {})
    held = out["poses_c2w"][5:]
    np.testing.assert_allclose(held, np.repeat(held[:1], 3, 0), atol=1e-6)
    np.testing.assert_allclose(held[0], out["poses_c2w"][4], atol=1e-3)  # stage 2 moved frame 4 by 0.1 mm
    assert abs(out["poses_c2w"][4, 0, 3] - 0.2) < 0.01  # the frames seen are placed (5 cm a frame)


def test_masks_over_every_track_hold_the_camera_and_say_so():
    """Every track masked (e.g. inverted masks): no static track, so the poses stay the first frame's, and the run
    says so on one line (a warning, since a fixed camera filming movers is a legitimate input)."""
    tr, prior, poses, *_ = _wall_scene()
    masks = np.ones(prior.shape, bool)
    with pytest.warns(RuntimeWarning, match=r"no static track to place the cameras on \(the masks cover 100% of"):
        out = world.optimise(tr, prior, masks, K, OptimConfig(verbose=False), {})
    np.testing.assert_allclose(out["poses_c2w"], np.tile(np.eye(4), (len(poses), 1, 1)), atol=1e-6)
    assert out["info"]["pose_warning"].startswith("no static track")
    # unmasked, the same scene places its cameras and says nothing
    quiet = world.optimise(tr, prior, np.zeros(prior.shape, bool), K, OptimConfig(verbose=False), {})
    assert quiet["info"]["pose_warning"] is None and np.ptp(quiet["poses_c2w"][:, 0, 3]) > 0.3
