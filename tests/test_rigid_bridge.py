"""optim.rigid_bridge: the groups of one rigid object on either side of a gap no track crosses, joined."""

import numpy as np
from scipy.spatial.transform import Rotation

from test_rigid import H, T, W, _lift, _scene
from trackingworld.config import OptimConfig
from trackingworld.geometry import intrinsics_matrix, invert_pose, look_at, transform
from trackingworld.optim.rigid import RigidSettings, rigid_movers
from trackingworld.optim.rigid_bridge import BridgeSettings, RigidObject, constant_velocity, crossing_transform, join

LAST_A, FIRST_B = 6, 10  # the first half of the tracks is seen in frames 0-6, the second in 10-15


def _split(uv, vis, seed: int = 0):
    """The scene's tracks cut at a gap: the first half seen up to LAST_A, the other from FIRST_B, queried there."""
    rng = np.random.default_rng(seed)
    n = len(vis)
    a = np.zeros(n, bool)
    a[: n // 2] = True
    vis = vis.copy()
    vis[a, LAST_A + 1:] = False
    vis[~a, :FIRST_B] = False
    qf = np.where(a, rng.integers(0, LAST_A + 1, n), rng.integers(FIRST_B, T, n))
    return vis, qf, a


def _poses(motion_rotvec, motion_t, frames):
    out = np.tile(np.eye(4), (len(frames), 1, 1))
    out[:, :3, :3] = Rotation.from_rotvec(np.outer(frames, motion_rotvec)).as_matrix()
    out[:, :3, 3] = np.outer(frames, motion_t)
    return out


def test_constant_velocity_continues_a_constant_motion():
    frames = np.arange(8)
    O = np.full((20, 4, 4), np.nan)
    O[frames] = _poses([0.0, 0.05, 0.01], [0.03, 0.0, -0.02], frames)
    at = np.array([9, 12, 19])
    got = constant_velocity(O, np.zeros(3), frames, at)
    np.testing.assert_allclose(got, _poses([0.0, 0.05, 0.01], [0.03, 0.0, -0.02], at), atol=1e-9)


def test_the_groups_of_one_object_across_a_gap_are_joined_and_placed_on_both_sides():
    uv, vis, X, z, poses, K, _ = _scene(rigid=True)
    vis, qf, a = _split(uv, vis)
    start = np.where(vis[..., None], _lift(uv, z, poses, K), 0.0)  # hidden frames: nothing known (at the origin)
    s = RigidSettings(min_tracks=150, ring_seeds=30)
    out, groups, _, info = rigid_movers(uv, vis, z, start, poses, K, qf, OptimConfig(), s, size=(W, H))
    assert info["rigid_groups"] == 2 and info["rigid_joined"] == 1
    assert len(np.unique(groups[groups >= 0])) == 1
    grouped = groups >= 0
    for who, frames in ((a, np.arange(FIRST_B, T)), (~a, np.arange(LAST_A + 1)),
                        (None, np.arange(LAST_A + 1, FIRST_B))):
        sel = grouped if who is None else grouped & who
        err = np.linalg.norm(out[sel][:, frames] - X[sel][:, frames], axis=-1)
        assert sel.sum() > 100 and np.median(err) < 0.02, (frames, np.median(err))
    # not joined: the first group's tracks keep what they were given after the gap
    out0, _, _, info0 = rigid_movers(uv, vis, z, start, poses, K, qf, OptimConfig(),
                                  RigidSettings(min_tracks=150, ring_seeds=30, bridge=None), size=(W, H))
    assert info0["rigid_groups"] == 2 and "rigid_joined" not in info0
    np.testing.assert_array_equal(out0[a][:, FIRST_B:], 0.0)


def _object(points, motion, frames, K, poses):
    """A RigidObject seen in ``frames`` and its tracks' uv [n,T,2] and vis [n,T]."""
    O = np.full((T, 4, 4), np.nan)
    O[frames] = motion[frames]
    cam = transform((invert_pose(poses) @ motion)[None], points[:, None, :])
    uv = np.stack([K[0, 0] * cam[..., 0] / cam[..., 2] + K[0, 2], K[1, 1] * cam[..., 1] / cam[..., 2] + K[1, 2]], -1)
    vis = np.zeros((len(points), T), bool)
    vis[:, frames] = True
    return O, uv, vis


def test_join_needs_the_later_group_where_the_earlier_one_would_be():
    rng = np.random.default_rng(2)
    K = intrinsics_matrix(250.0, 250.0, W / 2, H / 2)
    poses = np.stack([look_at(np.array([0.0, 0.0, -4.0]), np.zeros(3))] * T)
    pts = rng.uniform(-0.3, 0.3, (400, 3))
    frames = np.arange(T)
    moving = _poses([0.0, 0.03, 0.0], [0.04, 0.0, 0.0], frames)
    moving[:, :3, 3] += [-0.3, 0.0, 0.0]
    Oa, uva, visa = _object(pts[:200], moving, np.arange(LAST_A + 1), K, poses)
    a = RigidObject(Oa, np.arange(200), pts[:200], visa.copy())
    size, s = (W, H), BridgeSettings()
    for shift, joined in ((0.0, True), (0.8, False)):  # the same object; one 0.8 m to the side, moving alike
        other = moving.copy()
        other[:, 0, 3] += shift
        Ob, uvb, visb = _object(pts[200:], other, np.arange(FIRST_B, T), K, poses)
        b = RigidObject(Ob, np.arange(200, 400), pts[200:], visb.copy())
        uv, vis = np.r_[uva, uvb], np.r_[visa, visb]
        xyz = np.zeros(uv.shape[:2] + (3,))  # no track crosses the gap: not read
        new, frac = join(a, b, uv, vis, xyz, poses, K, size, s)
        assert (new is not None) == joined, frac
        assert join(b, a, uv, vis, xyz, poses, K, size, s)[0] is None  # b starts after a ends, not before
        if joined:
            assert frac > 0.9
            np.testing.assert_allclose(new.motion[FIRST_B:], moving[FIRST_B:], atol=2e-3)
            np.testing.assert_allclose(new.motion[LAST_A + 1:FIRST_B], moving[LAST_A + 1:FIRST_B], atol=2e-3)
        else:
            assert frac < 0.1


def test_join_needs_the_later_group_at_the_depth_the_earlier_one_would_be():
    """A second object twice as far and twice as large, moving alike, projects where the first would be: it lands
    on the image of the first's extension but not at its depth."""
    rng = np.random.default_rng(4)
    K = intrinsics_matrix(250.0, 250.0, W / 2, H / 2)
    centre = np.array([0.0, 0.0, -4.0])
    poses = np.stack([look_at(centre, np.zeros(3))] * T)
    pts = rng.uniform(-0.3, 0.3, (400, 3))
    moving = _poses([0.0, 0.03, 0.0], [0.04, 0.0, 0.0], np.arange(T))
    moving[:, :3, 3] += [-0.3, 0.0, 0.0]
    Oa, uva, visa = _object(pts[:200], moving, np.arange(LAST_A + 1), K, poses)
    a = RigidObject(Oa, np.arange(200), pts[:200], visa.copy())
    far = moving.copy()  # world = centre + 2 (moving @ p - centre): the points 2p on this motion
    far[:, :3, 3] = 2 * moving[:, :3, 3] - centre
    Ob, uvb, visb = _object(2 * pts[200:], far, np.arange(FIRST_B, T), K, poses)
    b = RigidObject(Ob, np.arange(200, 400), 2 * pts[200:], visb.copy())
    uv, vis = np.r_[uva, uvb], np.r_[visa, visb]
    xyz = np.zeros(uv.shape[:2] + (3,))
    new, frac = join(a, b, uv, vis, xyz, poses, K, (W, H), BridgeSettings())
    assert new is None and frac < 0.1
    new, frac = join(a, b, uv, vis, xyz, poses, K, (W, H), BridgeSettings(depth_tol=0.0))  # the image alone
    assert new is not None and frac > 0.6


def test_tracks_seen_across_the_gap_give_the_transform_between_the_groups():
    rng = np.random.default_rng(3)
    K = intrinsics_matrix(250.0, 250.0, W / 2, H / 2)
    poses = np.stack([look_at(np.array([0.0, 0.0, -4.0]), np.zeros(3))] * T)
    pts = rng.uniform(-0.3, 0.3, (400, 3))
    frames = np.arange(T, dtype=float)
    # it speeds up: a constant-velocity extension misses where it is after the gap
    moving = _poses([0.0, 0.03, 0.0], [0.0, 0.0, 0.0], frames)
    moving[:, 0, 3] = -0.4 + 0.004 * frames ** 2
    M_true = _poses([0.2, -0.1, 0.3], [0.1, 0.2, -0.1], np.ones(1))[0]  # a's object frame -> b's
    Oa, uva, visa = _object(pts[:200], moving, np.arange(LAST_A + 1), K, poses)
    Ob, uvb, visb = _object(transform(M_true, pts[200:]), moving @ invert_pose(M_true), np.arange(FIRST_B, T), K,
                            poses)
    a = RigidObject(Oa, np.arange(200), pts[:200], visa.copy())
    b = RigidObject(Ob, np.arange(200, 400), transform(M_true, pts[200:]), visb.copy())
    uv, vis = np.r_[uva, uvb], np.r_[visa, visb]
    xyz = transform(moving[None], np.r_[pts[:200], pts[200:]][:, None, :])  # [N,T,3] true world positions
    s = BridgeSettings()
    no_cross, _ = join(a, b, uv, vis, xyz, poses, K, (W, H), s)
    vis[:30, FIRST_B + 2:] = True  # 30 tracks of a found again after the gap, in b's frames
    assert crossing_transform(a, b, xyz, vis, s) is not None
    np.testing.assert_allclose(crossing_transform(a, b, xyz, vis, s), M_true, atol=1e-9)
    new, frac = join(a, b, uv, vis, xyz, poses, K, (W, H), s)
    assert new is not None and frac > 0.9
    np.testing.assert_allclose(new.motion[FIRST_B:], moving[FIRST_B:], atol=1e-9)
    if no_cross is not None:  # without them, the extensions' guess is off by centimetres
        assert np.abs(no_cross.motion[FIRST_B:, :3, 3] - moving[FIRST_B:, :3, 3]).max() > 0.01
    vis[:30, FIRST_B + 2:] = False
    vis[:5, FIRST_B + 2:] = True  # too few to fit to
    assert crossing_transform(a, b, xyz, vis, s) is None
