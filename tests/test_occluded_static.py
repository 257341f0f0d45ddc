"""Dynamic-labelled tracks that are static points the 2D tracker followed onto a mover passing in front of them
(``optim.occluded_static``, ``OptimConfig.occluded_static_frames``)."""

import numpy as np
import pytest

from trackingworld.config import OptimConfig
from trackingworld.geometry import invert_pose, project, transform, unproject
from trackingworld.optim.occluded_static import static_behind_occluders
from trackingworld.pipeline.static_side import occlusion_rescue

K = np.array([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]])
T, H, W = 8, 48, 64
WALL = 5.0  # metres


def _setup():
    """A camera sliding right past a wall at 5 m; a box at 2 m covers the image's columns 20-44 in frames 3-5."""
    poses = np.tile(np.eye(4), (T, 1, 1))
    poses[:, 0, 3] = 0.05 * np.arange(T)
    depth = np.full((T, H, W), WALL)
    depth[3:6, :, 20:45] = 2.0
    return poses, depth


def _projections(uv_q, poses):
    """[n,T,2] the wall points under the query pixels (frame 0) in every frame."""
    X = transform(poses[0], unproject(uv_q, np.full(len(uv_q), WALL), K))
    w2c = invert_pose(poses)
    return np.stack([project(transform(w2c[t], X), K)[0] for t in range(T)], 1)


def _tracks():
    """Four tracks from frame 0: 0 a wall point the tracker drags 6 px along with the box while it hides the point;
    1 a mover sliding 3 px a frame; 2 a wall point whose track slides 6 px in frames 3-5 with nothing in front
    (a slow mover a static point explains elsewhere); 3 as 0, dragged in one frame only."""
    poses, depth = _setup()
    uv_q = np.array([[33.0, 20.0], [30.0, 30.0], [10.0, 10.0], [34.0, 30.0]])
    uv = _projections(uv_q, poses)
    uv[0, 3:6, 0] += 6.0
    uv[1] += 3.0 * np.arange(T)[:, None] * np.array([1.0, 0.0])
    uv[2, 3:6, 0] += 6.0
    uv[3, 4, 0] += 6.0
    return uv.astype(np.float32), np.ones((4, T), bool), np.zeros(4, np.int64), poses, depth


def test_a_point_dragged_behind_an_occluder_is_static_the_others_are_not():
    uv, vis, qf, poses, depth = _tracks()
    static, X, pix, seen = static_behind_occluders(uv, vis, qf, np.full(4, WALL), poses, K, depth)
    assert static.tolist() == [True, False, False, False]
    truth = _projections(uv[:1, 0].astype(np.float64), poses)
    np.testing.assert_allclose(pix[0], truth[0], atol=1e-4)  # its 2D track: the point's projection
    assert seen[0].tolist() == [True, True, True, False, False, False, True, True]  # hidden frames not seen
    np.testing.assert_allclose(X[0, 2], WALL)
    # the hidden frames' evidence required: one dragged frame is enough when asked for
    assert static_behind_occluders(uv, vis, qf, np.full(4, WALL), poses, K, depth, min_hidden=1)[0][3]
    # a nearer surface only 5% in front does not count as hiding the point with the default 0.9
    shallow = np.where(depth < WALL, 0.95 * WALL, WALL)
    assert not static_behind_occluders(uv, vis, qf, np.full(4, WALL), poses, K, shallow)[0].any()
    assert static_behind_occluders(uv, vis, qf, np.full(4, WALL), poses, K, shallow, in_front=0.97)[0][0]


def test_too_few_frames_in_view_or_off_the_point_there_is_not_static():
    uv, vis, qf, poses, depth = _tracks()
    vis2 = vis.copy()
    vis2[0, [1, 2, 6]] = False  # in view in frame 7 alone
    assert not static_behind_occluders(uv, vis2, qf, np.full(4, WALL), poses, K, depth)[0][0]
    vis2[0, 6] = True  # in frames 6 and 7: enough with 2 (the default), not with 3
    assert static_behind_occluders(uv, vis2, qf, np.full(4, WALL), poses, K, depth, min_frames=2)[0][0]
    assert not static_behind_occluders(uv, vis2, qf, np.full(4, WALL), poses, K, depth, min_frames=3)[0][0]
    uv2 = uv.copy()
    uv2[0, 6:, 0] += 4.0  # off the point in 2 of its 4 in-view frames
    assert not static_behind_occluders(uv2, vis, qf, np.full(4, WALL), poses, K, depth)[0][0]
    assert static_behind_occluders(uv2, vis, qf, np.full(4, WALL), poses, K, depth, frac=0.5)[0][0]


def test_occlusion_rescue_updates_labels_points_and_tracks():
    uv, vis, qf, poses, depth = _tracks()
    dynamic = np.array([True, True, True, False])
    xyz = np.zeros((4, T, 3), np.float32)
    uv0, vis0 = uv.copy(), vis.copy()
    info = {}
    uv2, vis2, moved = occlusion_rescue(uv, vis, qf, depth, poses, K, OptimConfig(), dynamic, xyz, info)
    assert moved.tolist() == [0] and dynamic.tolist() == [False, True, True, False]
    assert info["occluded_static"] == {"tested": 3, "static": 1} and info["dynamic"] == 2
    np.testing.assert_array_equal(uv, uv0)  # the caller's arrays are not written
    np.testing.assert_array_equal(vis, vis0)
    assert not vis2[0, 3:6].any() and vis2[0, [0, 1, 2, 6, 7]].all() and vis2[1:].all()
    np.testing.assert_allclose(xyz[0], np.repeat(xyz[0, :1], T, 0))
    np.testing.assert_allclose(xyz[0, 0], [(33 - 32) / 100 * WALL, (20 - 24) / 100 * WALL, WALL], atol=1e-5)
    np.testing.assert_allclose(uv2[0, 4], _projections(uv[:1, 0].astype(np.float64), poses)[0, 4], atol=1e-3)
    # off: nothing tested, nothing changed
    dyn = np.array([True, True, True, False])
    same = occlusion_rescue(uv, vis, qf, depth, poses, K, OptimConfig(occluded_static_frames=0), dyn, xyz, {})
    assert same[0] is uv and same[1] is vis and len(same[2]) == 0 and dyn[:3].all()
    # in place (the pipeline's own copies): the same tracks written into the given arrays
    mine_uv, mine_vis = uv.copy(), vis.copy()
    own = occlusion_rescue(mine_uv, mine_vis, qf, depth, poses, K, OptimConfig(), np.array([True, True, True, False]),
                           np.zeros((4, T, 3), np.float32), {}, in_place=True)
    assert own[0] is mine_uv and own[1] is mine_vis
    np.testing.assert_array_equal(mine_uv, uv2)
    np.testing.assert_array_equal(mine_vis, vis2)


@pytest.mark.parametrize("bad", [dict(occluded_static_frames=-1), dict(occluded_static_frac=1.5),
                                 dict(occluded_static_px=0.0), dict(occluded_static_depth=1.2),
                                 dict(occluded_static_depth=0.0), dict(occluded_static_in_view=0)])
def test_out_of_range_settings_are_refused(bad):
    from trackingworld.errors import InputError
    from trackingworld.pipeline.world import check_optim

    with pytest.raises(InputError, match="occluded_static_frames .* the frames are 0 \\(off\\) or more"):
        check_optim(OptimConfig(**bad))


def test_the_cli_flags_reach_the_config():
    from trackingworld.cli.main import _optim_config, build_parser

    cfg = _optim_config(build_parser().parse_args(["run", "x", "--out", "o", "--occluded-static", "3",
                                                   "--occluded-static-frac", "0.7", "--occluded-static-px", "1.5",
                                                   "--occluded-static-depth", "0.8",
                                                   "--occluded-static-in-view", "4", "--photo-moving", "0.3"]))
    assert cfg.photo_moving_share == 0.3
    assert (cfg.occluded_static_frames, cfg.occluded_static_frac, cfg.occluded_static_px,
            cfg.occluded_static_depth, cfg.occluded_static_in_view) == (3, 0.7, 1.5, 0.8, 4)
    d = _optim_config(build_parser().parse_args(["run", "x", "--out", "o"]))
    assert d.occluded_static_frames == OptimConfig().occluded_static_frames == 2


def test_the_photometric_test_skips_the_frames_where_the_point_is_hidden():
    """The photometric test (``optim.photo_static``) with the video depth: a wall point behind the box in frames 3-5
    shows the box's colour there; those frames are not tested, so it passes, and fails when they are."""
    from trackingworld.optim.photo_static import static_hypothesis

    poses, depth = _setup()
    frames = np.full((T, H, W, 3), 100, np.uint8)
    frames[3:6, :, 20:45] = (200, 50, 50)
    open_ = np.ones((T, H, W), bool)
    args = (np.array([[33.0, 20.0]]), np.array([WALL]), np.zeros(1, np.int64), poses, K, frames, open_)
    assert not static_hypothesis(*args)[0][0]  # 4 of 7 frames match
    static, _, _, seen = static_hypothesis(*args, depth=depth)
    assert static[0] and seen[0].tolist() == [True, True, True, False, False, False, True, True]
    assert not static_hypothesis(*args, depth=depth, in_front=0.3)[0][0]  # the box is not nearer than 0.3x


def _box_leaving():
    """A still camera before the wall; a red box 2 m away, at columns 20-30 in frame 0, moves right 6 px a frame
    and no mask covers it. Tracks from frame 0: on the box (seen in frames 0-2), on the wall (seen throughout), and
    on the wall where the box passes in front of it in frames 4-5."""
    poses = np.tile(np.eye(4), (T, 1, 1))
    frames = np.full((T, H, W, 3), 100, np.uint8)
    depth = np.full((T, H, W), WALL)
    for t in range(T):
        frames[t, :, 20 + 6 * t:31 + 6 * t] = (200, 40, 40)
        depth[t, :, 20 + 6 * t:31 + 6 * t] = 2.0
    uv = np.zeros((3, T, 2), np.float32)
    uv[0] = [[25.0 + 6 * t, 24.0] for t in range(T)]
    uv[1] = [10.0, 10.0]
    uv[2] = [50.0, 24.0]
    vis = np.ones((3, T), bool)
    vis[0, 3:] = False
    return uv, vis, np.zeros(3, np.int64), poses, frames, np.zeros((T, H, W), bool), depth


def test_photo_moving_finds_a_short_track_whose_point_shows_the_background_after_it_left():
    from trackingworld.optim.labels import DYNAMIC, STATIC
    from trackingworld.pipeline.static_side import photo_moving

    uv, vis, qf, poses, frames, masks, depth = _box_leaving()
    labels = np.full(3, STATIC, np.int8)
    dynamic = np.zeros(3, bool)
    info = {}
    moved = photo_moving(uv, vis, qf, depth, poses, K, frames, masks, OptimConfig(photo_moving_share=0.2), dynamic,
                         labels, info)
    assert moved.tolist() == [0] and dynamic.tolist() == [True, False, False]
    assert info["photo_moving"] == {"tested": 3, "dynamic": 1} and info["dynamic"] == 1
    # the default finds it too; 0 turns the test off; a track seen in more than vote_short frames, or one the masks
    # do not call static, is not tested
    dyn = np.zeros(3, bool)
    assert photo_moving(uv, vis, qf, depth, poses, K, frames, masks, OptimConfig(), dyn, labels, {}).tolist() == [0]
    for cfg, lab in ((OptimConfig(photo_moving_share=0.0), labels), (OptimConfig(vote_short=2), labels),
                     (OptimConfig(), np.full(3, DYNAMIC, np.int8))):
        dyn = np.zeros(3, bool)
        assert len(photo_moving(uv, vis, qf, depth, poses, K, frames, masks, cfg, dyn, lab, {})) == 0
        assert not dyn.any()
    from trackingworld.errors import InputError
    from trackingworld.pipeline.world import check_optim

    with pytest.raises(InputError, match="photo_moving_share 1.5: a share from 0 \\(off\\) to 1"):
        check_optim(OptimConfig(photo_moving_share=1.5))


def test_photo_moving_leaves_out_the_tracks_queried_at_the_images_edge():
    """The box of :func:`_box_leaving` starting at the image's left edge: its track queried 2 px from the edge is
    not tested (the edge's blur and the view it soon leaves), the one queried 3 px from it is, and is found."""
    from trackingworld.optim.labels import STATIC
    from trackingworld.pipeline.static_side import PHOTO_MOVING_EDGE_PX, photo_moving

    uv, vis, qf, poses, frames, masks, depth = _box_leaving()
    frames = np.roll(frames, -20, axis=2)  # the box at columns 0-10 in frame 0
    depth = np.roll(depth, -20, axis=2)
    uv[1] = [40.0, 10.0]  # the wall track, where the box passes later (hidden there, not tested)
    assert PHOTO_MOVING_EDGE_PX == 2.0
    got = {}
    for x0 in (2.0, 3.0):
        uv[0] = [[x0 + 6 * t, 24.0] for t in range(T)]
        dynamic, info = np.zeros(3, bool), {}
        got[x0] = photo_moving(uv, vis, qf, depth, poses, K, frames, masks, OptimConfig(photo_moving_share=0.2),
                               dynamic, np.full(3, STATIC, np.int8), info)
        assert info["photo_moving"]["tested"] == (2 if x0 == 2.0 else 3)
    assert got[2.0].tolist() == [] and got[3.0].tolist() == [0]
