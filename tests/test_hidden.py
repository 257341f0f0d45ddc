"""Dynamic tracks through the frames they are not visible: carried by their neighbours' motion."""

import numpy as np

from trackingworld.optim.hidden import carry_hidden, weighted_median
from trackingworld.tracking2d.base import hold_invisible, nearest_visible_frame


def _moving_cloud(N=60, T=12, seed=0):
    rng = np.random.default_rng(seed)
    base = rng.normal(size=(N, 3)) * 0.2 + np.array([0.0, 0.0, 4.0])
    vel = np.array([0.05, -0.02, 0.01])
    xyz = base[:, None] + vel * np.arange(T)[None, :, None]  # [N,T,3] a translating rigid object
    return xyz, rng


def test_nearest_visible_frame_prefers_earlier_on_ties():
    vis = np.array([[False, True, False, False, False, True]])
    assert nearest_visible_frame(vis).tolist() == [[1, 1, 1, 1, 5, 5]]
    assert nearest_visible_frame(np.zeros((1, 3), bool)).tolist() == [[0, 1, 2]]


def test_translation_is_carried_exactly_where_held_positions_lag():
    xyz, rng = _moving_cloud()
    N, T = xyz.shape[:2]
    vis = np.ones((N, T), bool)
    hidden = rng.random((N, T)) < 0.3
    hidden[:, 0] = False  # every track keeps a visible frame
    vis &= ~hidden
    given = np.where(vis[..., None], xyz, 1e3)  # hidden frames hold garbage: they must not be read
    out = carry_hidden(given, vis, k=8)
    err = np.linalg.norm(out - xyz, axis=-1)
    held = np.linalg.norm(hold_invisible(xyz, vis) - xyz, axis=-1)
    assert np.all(err[vis] == 0)
    assert err[~vis].max() < 1e-6  # float32 steps
    assert held[~vis].mean() > 0.02  # the old behaviour is visibly wrong on the same input


def test_rotation_is_carried_to_first_order():
    rng = np.random.default_rng(1)
    N, T = 80, 10
    base = rng.normal(size=(N, 3)) * 0.1
    ang = np.deg2rad(2.0) * np.arange(T)
    c, s = np.cos(ang), np.sin(ang)
    Rz = np.zeros((T, 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, -s, s, c, 1
    xyz = np.einsum("tij,nj->nti", Rz, base) + np.array([0.0, 0.0, 3.0])
    vis = np.ones((N, T), bool)
    vis[:20, 5:] = False
    out = carry_hidden(xyz, vis, k=8)
    err = np.linalg.norm(out - xyz, axis=-1)[~vis]
    held = np.linalg.norm(hold_invisible(xyz, vis) - xyz, axis=-1)[~vis]
    assert err.mean() < 0.5 * held.mean()  # a neighbour's displacement differs by omega x (its offset)


def test_without_a_neighbour_visible_the_position_is_held():
    xyz, _ = _moving_cloud(N=3, T=5)
    vis = np.zeros((3, 5), bool)
    vis[0, :2] = True  # track 0 seen in frames 0-1 only
    vis[1, :2] = True  # its only neighbours are seen in the same frames
    vis[2, :2] = True
    out = carry_hidden(xyz, vis, k=2)
    assert np.allclose(out[0, 2:], xyz[0, 1])
    never = carry_hidden(xyz, np.zeros((3, 5), bool))
    assert np.array_equal(never, xyz)


def test_a_bunch_lost_together_is_carried_by_the_tracks_still_visible():
    # a dense patch of tracks is lost from frame 4 on; its nearest neighbours are all in the patch, so only
    # tracks farther away on the same (translating) object are visible at the hidden frames
    rng = np.random.default_rng(2)
    N, T = 200, 10
    base = rng.uniform(-0.2, 0.2, size=(N, 3)) + np.array([0.0, 0.0, 4.0])
    patch = np.linalg.norm(base[:, :2] - base[0, :2], axis=1) < 0.08
    vel = np.array([0.04, 0.01, -0.02])
    xyz = base[:, None] + vel * np.arange(T)[None, :, None]
    vis = np.ones((N, T), bool)
    vis[patch, 4:] = False
    out = carry_hidden(np.where(vis[..., None], xyz, np.nan), vis, k=8)
    err = np.linalg.norm(out - xyz, axis=-1)[~vis]
    held = np.linalg.norm(hold_invisible(xyz, vis) - xyz, axis=-1)[~vis]
    assert patch.sum() >= 16  # more than k: the old rule (k nearest at s, then visible at t) found none
    assert err.max() < 1e-6
    assert held.mean() > 0.05


def test_a_donor_on_another_object_beyond_reach_is_left_out():
    # track 0 is hidden at frame 2; its object's other track is 5 cm away and still, another object 1 m away
    # moves by 1 m: only the near donor counts
    xyz = np.zeros((3, 3, 3))
    xyz[1] = [0.05, 0.0, 4.0]
    xyz[0] = [0.0, 0.0, 4.0]
    xyz[2, :, 0] = 1.0
    xyz[2, :, 2] = 4.0
    xyz[2, 2, 1] = 1.0
    vis = np.ones((3, 3), bool)
    vis[0, 2] = False
    out = carry_hidden(xyz, vis, k=2, reach=0.3)
    assert np.allclose(out[0, 2], xyz[0, 1])
    far = carry_hidden(xyz, vis, k=2, reach=2.0, stat="mean")  # within reach: its motion is mixed in
    assert far[0, 2, 1] > 0.01


def test_the_median_step_ignores_a_minority_of_donors_on_another_object():
    # track 0 is hidden at frame 2; five tracks of its own (still) object lie 4-8 cm from it, two of another
    # object passing 3-4 cm away in frame 1 (within reach, nearer than most) move 0.25 m by frame 2: the weighted
    # mean takes part of that motion, the median none
    rng = np.random.default_rng(3)
    T = 3
    own = np.array([0.0, 0.0, 4.0]) + np.c_[rng.uniform(0.04, 0.08, 5) * np.array([1, -1, 1, -1, 1]),
                                            rng.uniform(-0.01, 0.01, 5), np.zeros(5)]
    other = np.array([[0.0, 0.03, 4.0], [0.0, -0.04, 4.0]])
    xyz = np.concatenate([np.array([[0.0, 0.0, 4.0]]), own, other])[:, None].repeat(T, 1)
    xyz[6:, :, 1] += 0.25 * (np.arange(T) - 1)  # the other object moves 0.25 m a frame, passing at frame 1
    vis = np.ones((len(xyz), T), bool)
    vis[0, 2] = False
    mean = carry_hidden(xyz, vis, k=8, reach=0.3, stat="mean")
    median = carry_hidden(xyz, vis, k=8, reach=0.3)  # the default
    assert mean[0, 2, 1] > 0.05
    assert abs(median[0, 2, 1]) < 1e-6


def test_weighted_median_is_the_median_under_weights():
    v = np.array([[[0.0], [1.0], [10.0]], [[5.0], [1.0], [2.0]]])
    assert weighted_median(v, np.ones((2, 3)))[:, 0].tolist() == [1.0, 2.0]
    assert weighted_median(v, np.array([[1.0, 1.0, 5.0], [3.0, 1.0, 1.0]]))[:, 0].tolist() == [10.0, 5.0]


def test_gaps_between_searched_ones_take_interpolated_steps():
    # a track lost after frame 0 of 60 on a uniformly moving object: most gaps are not searched, and each takes
    # the step interpolated between searched ones, exact for uniform motion
    from trackingworld.optim.hidden import searched_gaps

    xyz, rng = _moving_cloud(N=40, T=60)
    vis = np.ones((40, 60), bool)
    vis[0, 1:] = False
    gaps = searched_gaps(60)
    assert gaps[0] == 1 and gaps[-1] <= 59 and len(gaps) < 40 and np.all(np.diff(gaps) > 0)
    out = carry_hidden(xyz, vis, k=4)
    assert np.abs(out[0] - xyz[0]).max() < 1e-5


def test_the_result_does_not_depend_on_the_threads():
    # many (anchor, frame) pairs on a rotating object with random losses: one thread and several give the same
    # array to the bit (each pair's step is written once, by its own search)
    rng = np.random.default_rng(3)
    N, T = 300, 30
    base = rng.normal(size=(N, 3)) * 0.3 + np.array([0.0, 0.0, 5.0])
    ang = np.deg2rad(2.0) * np.arange(T)
    c, s = np.cos(ang), np.sin(ang)
    R = np.zeros((T, 3, 3))
    R[:, 0, 0], R[:, 0, 2], R[:, 1, 1], R[:, 2, 0], R[:, 2, 2] = c, s, 1, -s, c
    centre = np.array([0.0, 0.0, 5.0])
    xyz = np.einsum("tij,nj->nti", R, base - centre) + centre + 0.03 * np.arange(T)[None, :, None]
    vis = rng.random((N, T)) > 0.4
    one = carry_hidden(xyz, vis, k=8, threads=1)
    assert np.array_equal(one, carry_hidden(xyz, vis, k=8, threads=4))
    hidden = ~vis & vis.any(1, keepdims=True)
    carried = np.linalg.norm(one - xyz, axis=-1)[hidden]  # and it is carried, not held
    held = np.linalg.norm(hold_invisible(xyz, vis) - xyz, axis=-1)[hidden]
    assert carried.mean() < 0.2 * held.mean() and held.mean() > 0.03


def _project(xyz, f=300.0, c=(160.0, 120.0)):
    """[N,T,3] camera-frame points (an identity camera) -> [N,T,2] px."""
    return f * xyz[..., :2] / xyz[..., 2:] + np.asarray(c)


def test_image_velocity_to_the_previous_frame_else_from_the_next():
    from trackingworld.optim.hidden import image_velocity

    uv = np.zeros((2, 5, 2), np.float32)
    uv[:, :, 0] = np.arange(5) * np.array([[2.0], [-1.0]])  # 2 and -1 px per frame along x
    vis = np.array([[True, True, False, True, True], [False, False, True, False, False]])
    vel, known = image_velocity(uv, vis)  # [T,N,2], [T,N]
    assert known.T.tolist() == [[True, True, False, True, True], [False] * 5]
    assert np.allclose(vel[[0, 1, 3, 4], 0, 0], 2.0)  # frame 0 from the next, 1 and 4 to the previous
    assert np.all(vel[:, 1] == 0)  # seen once: unknown


def test_objects_passing_each_other_lend_no_motion_with_the_image_motion():
    # two clouds that overlap in 3D at frame 4 move in opposite directions; some of A's tracks are lost after
    # frame 4: by 3D distance alone half their donors are B's, with the image motion they are A's
    rng = np.random.default_rng(4)
    N, T, s = 150, 10, 4
    t = np.arange(T)[None, :, None] - s
    a = rng.uniform(-0.15, 0.15, (N, 3)) + np.array([0.0, 0.0, 4.0])
    b = rng.uniform(-0.15, 0.15, (N, 3)) + np.array([0.0, 0.0, 4.0])
    xyz = np.concatenate([a[:, None] + np.array([0.05, 0.0, 0.0]) * t, b[:, None] + np.array([-0.05, 0.0, 0.0]) * t])
    vis = np.ones((2 * N, T), bool)
    vis[:30, s + 1:] = False
    scale = 8 * 4.0 / 300.0  # metres per px per frame: 8 frames' drift at 4 m, f = 300 px
    by_position = carry_hidden(xyz, vis, k=8)
    with_motion = carry_hidden(xyz, vis, k=8, uv=_project(xyz), motion_scale=scale)
    err_p = np.linalg.norm(by_position - xyz, axis=-1)[~vis]
    err_m = np.linalg.norm(with_motion - xyz, axis=-1)[~vis]
    assert err_p.mean() > 0.05  # B's motion mixed in
    assert err_m.max() < 1e-5  # A's alone: its translation, exactly
    assert np.array_equal(carry_hidden(xyz, vis, k=8, uv=_project(xyz), motion_scale=0.0), by_position)


def test_a_track_seen_once_takes_the_velocity_of_its_nearest_tracks_in_3d():
    from trackingworld.optim.hidden import _impute_velocity

    rng = np.random.default_rng(5)
    pos = np.concatenate([rng.normal(size=(20, 3)) * 0.05, rng.normal(size=(20, 3)) * 0.05 + [1.0, 0.0, 0.0]])
    pos = np.concatenate([pos, [[0.01, 0.0, 0.0], [0.99, 0.0, 0.0]]])[None].astype(np.float32)  # [1,42,3]
    vel = np.zeros((1, 42, 2), np.float32)
    vel[0, :20] = [3.0, 0.0]  # the cluster at the origin moves right, the one at x = 1 m left
    vel[0, 20:40] = [-2.0, 1.0]
    known = np.ones((1, 42), bool)
    known[0, 40:] = False  # the last two: seen once, one in each cluster
    vis_t = np.ones((1, 42), bool)
    _impute_velocity(vel, known, pos, vis_t)
    assert np.allclose(vel[0, 40], [3.0, 0.0]) and np.allclose(vel[0, 41], [-2.0, 1.0])


def test_carrying_in_place_and_by_rows_gives_the_numbers_of_copies():
    # the pipeline's carrying writes its own positions in place and reads the pixels of the dynamic rows of the
    # whole [N,T,2] array (on a long video each copy is gigabytes): the same numbers as copies
    xyz, rng = _moving_cloud(N=80, T=10, seed=3)
    xyz = xyz.astype(np.float32)
    vis = rng.random(xyz.shape[:2]) > 0.3
    vis[:, 0] = True
    uv = _project(xyz).astype(np.float32)
    others = (_project(xyz + 1.0) + 7.0).astype(np.float32)  # rows the carrying must not read
    whole = np.concatenate([others[:20], uv, others[20:]])
    rows = np.arange(20, 100)
    ref = carry_hidden(xyz, vis, k=8, uv=uv, motion_scale=0.1)
    mine = xyz.copy()
    out = carry_hidden(mine, vis, k=8, uv=whole, rows=rows, motion_scale=0.1, overwrite=True)
    assert out is mine and np.array_equal(out, ref)
    assert not np.array_equal(ref, carry_hidden(xyz, vis, k=8, uv=whole[:80], motion_scale=0.1))  # rows are read

