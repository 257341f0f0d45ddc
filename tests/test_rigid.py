"""optim.rigid: a rigid mover placed by its rigid motion, its scale from the depth targets of all frames."""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from trackingworld.config import OptimConfig
from trackingworld.geometry import camera_depths, intrinsics_matrix, invert_pose, look_at, project, transform
from trackingworld.optim.rigid import RigidSettings, initial_motion, rigid_movers

T, W, H = 16, 320, 240


def _camera():
    """K and the camera-to-world poses [T,4,4] of a camera 3 m from the origin moving sideways 5 cm a frame."""
    K = intrinsics_matrix(250.0, 250.0, W / 2, H / 2)
    return K, np.stack([look_at(np.array([0.05 * t, 0.0, -3.0]), np.array([0.05 * t, 0.0, 0.0])) for t in range(T)])


def _scene(rigid: bool, seed: int = 0):
    """A box of points seen by a camera moving sideways; it moves and spins (rigid) or every point wanders
    on its own (not rigid). Returns uv, vis, true world points [N,T,3], poses, K, query frames."""
    rng = np.random.default_rng(seed)
    K, poses = _camera()
    P = rng.uniform(-0.4, 0.4, (600, 3))  # object frame
    P[:, 2] = np.where(rng.random(600) < 0.5, -0.4, P[:, 2])  # much of it on the face towards the camera
    X = np.empty((len(P), T, 3))
    for t in range(T):
        R = Rotation.from_rotvec([0.0, np.deg2rad(3.0) * t, 0.0]).as_matrix()
        X[:, t] = P @ R.T + np.array([0.03 * t, 0.01 * t, 0.02 * t])
        if not rigid:
            X[:, t] += rng.normal(0, 0.02 * np.sqrt(t), (len(P), 3))
    uv, z = project(transform(invert_pose(poses)[None], X), K)
    return uv, np.ones((len(P), T), bool), X, z, poses, K, rng.integers(0, T, len(P))


def _lift(uv, z, poses, K):
    x = (uv[..., 0] - K[0, 2]) / K[0, 0] * z
    y = (uv[..., 1] - K[1, 2]) / K[1, 1] * z
    return transform(poses[None], np.stack([x, y, z], -1))


def test_a_rigid_mover_takes_the_scale_of_all_frames():
    uv, vis, X, z, poses, K, qf = _scene(rigid=True)
    # a prior that is 10% too near in some frames and 10% too far in others, with 2% noise per pixel
    warp = 1 + 0.1 * np.sin(np.arange(T) / T * 2 * np.pi)[None]
    target = z * warp * (1 + 0.02 * np.random.default_rng(1).standard_normal(z.shape))
    start = _lift(uv, target, poses, K)
    out, groups, _, info = rigid_movers(uv, vis, target, start, poses, K, qf, OptimConfig(), RigidSettings())
    assert info["rigid_groups"] >= 1 and (groups >= 0).mean() > 0.75
    zo = camera_depths(out, poses)
    before = np.median(np.abs(np.log(target / z)), axis=0)  # per frame
    after = np.median(np.abs(np.log(zo / z)), axis=0)
    assert before.max() > 0.08 and after.max() < 0.03
    assert np.median(np.linalg.norm(out - X, axis=-1)) < 0.5 * np.median(np.linalg.norm(start - X, axis=-1))


def test_each_object_pose_carries_its_tracks_as_one_rigid_point_set():
    uv, vis, X, z, poses, K, qf = _scene(rigid=True)
    start = _lift(uv, z * 1.05, poses, K)
    out, groups, motions, info = rigid_movers(uv, vis, z * 1.05, start, poses, K, qf, OptimConfig(), RigidSettings())
    assert motions.shape == (info["rigid_groups"], T, 4, 4) and motions.shape[0] >= 1
    assert set(np.unique(groups)) <= {-1, *range(len(motions))}
    for g, O in enumerate(motions):
        solved = np.isfinite(O[:, 0, 0])
        assert solved.sum() >= 3 and np.isnan(O[~solved]).all()
        # in the object's frame every track of the object holds still: one point per track
        local = transform(invert_pose(O[solved])[None], out[groups == g][:, solved])
        assert np.abs(local - local[:, :1]).max() < 1e-6
        # and it moves as the truth does, at the scale of the depth targets (5% too far): the distances between its
        # tracks are the true ones times 1.05 in every frame
        i, j = np.flatnonzero(groups == g)[[0, -1]]
        ratio = np.linalg.norm(out[i] - out[j], axis=-1) / np.linalg.norm(X[i] - X[j], axis=-1)
        np.testing.assert_allclose(ratio[solved], 1.05, rtol=0.01)


def test_tracks_that_move_apart_keep_their_positions():
    uv, vis, X, z, poses, K, qf = _scene(rigid=False)
    start = _lift(uv, z * 1.05, poses, K)
    out, groups, _, info = rigid_movers(uv, vis, z * 1.05, start, poses, K, qf, OptimConfig(), RigidSettings())
    assert info["rigid_groups"] == 0 and (groups < 0).all()
    np.testing.assert_array_equal(out, start)


def test_initial_motion_chains_the_frames_and_stops_where_too_few_are_shared():
    uv, vis, X, *_ = _scene(rigid=True)
    vis = vis.copy()
    vis[:, 12:] = False
    vis[:3, 12:] = True  # three tracks seen on: too few to carry the chain past frame 11
    O = initial_motion(X, vis, 0)
    assert np.isfinite(O[:12]).all() and np.isnan(O[12:]).all()
    np.testing.assert_allclose(transform(O[5][None], X[:, 0]), X[:, 5], atol=1e-9)


def test_run_with_rigid_movers_times_the_step_and_keeps_the_result_contract(tiny_scene, tmp_path, monkeypatch):
    import json

    from trackingworld.cli.main import main
    from trackingworld.io.result import load_result
    from trackingworld.optim import stage2

    inp = tiny_scene / "input"
    outs = {}
    pose_fits = {}  # the poses-only fits of the frames between key frames, per run
    real = stage2.fit_poses
    monkeypatch.setattr(stage2, "fit_poses", lambda *a, **k: pose_fits.update(n=pose_fits.get("n", 0) + 1) or
                        real(*a, **k))
    for name, extra in (("off", ["--no-rigid-movers"]), ("on", []), ("keyed", ["--rigid-key-frames", "4"])):
        pose_fits["n"] = 0
        out = outs[name] = tmp_path / name
        assert main(["run", str(inp / "frames"), "--out", str(out), "--depth", str(inp / "depth.npy"),
                     "--masks", str(inp / "masks"), "--intrinsics", str(inp / "intrinsics.txt"), "--quiet",
                     *extra]) == 0
        pose_fits[name] = pose_fits["n"]
    # the tiny scene's groups are solved whole by default; with 4 key frames their other frames are fitted alone
    assert pose_fits["on"] == 0 and pose_fits["keyed"] > 0
    keyed = load_result(outs["keyed"])
    assert np.isfinite(keyed.tracks_3d).all() and len(keyed.object_poses) >= 1
    assert "rigid_movers" in json.loads((outs["on"] / "timings.json").read_text())
    assert "rigid_movers" not in json.loads((outs["off"] / "timings.json").read_text())
    a, b = load_result(outs["off"]), load_result(outs["on"])
    # the labels are decided before; the tests after stage 3 that read the video depth may move a few
    assert (a.is_dynamic == b.is_dynamic).mean() > 0.99
    both = a.is_dynamic & b.is_dynamic
    assert np.isfinite(b.tracks_3d).all() and not np.allclose(a.tracks_3d[both], b.tracks_3d[both])
    info = json.loads((outs["on"] / "optim.json").read_text())
    assert info["rigid_groups"] >= 1 and info["rigid_tracks"] >= 50
    # the objects in result.npz: none without the step; with it, dynamic tracks only, every object holding some,
    # and its tracks still in its frame over the frames its motion is solved in
    assert a.object_poses.shape == (0, a.num_frames, 4, 4) and (a.object_id == -1).all()
    G = len(b.object_poses)
    assert 1 <= G <= info["rigid_groups"] and (b.object_id[~b.is_dynamic] == -1).all()
    assert set(np.unique(b.object_id)) == {-1, *range(G)}
    for g, O in enumerate(b.object_poses.astype(np.float64)):
        solved = np.isfinite(O[:, 0, 0])
        local = transform(invert_pose(O[solved])[None], b.tracks_3d[b.object_id == g][:, solved].astype(np.float64))
        still = np.abs(local - local[:, :1]).max(axis=(1, 2)) < 1e-3
        assert still.mean() > 0.9


def test_the_median_scale_keeps_the_2d_tracks_and_meets_the_targets():
    from trackingworld.geometry import project
    from trackingworld.optim.rigid import _to_median_scale

    uv, vis, X, z, poses, K, qf = _scene(rigid=True)
    target = 1.07 * z * (1 + 0.01 * np.random.default_rng(2).standard_normal(z.shape))
    pos = X.copy()
    pos[:5, 3] = np.nan  # frames the motion does not solve stay unsolved
    out = _to_median_scale(pos, vis, target, poses)
    assert np.isnan(out[:5, 3]).all() and np.isfinite(out[5:]).all()
    ratio = target / camera_depths(np.nan_to_num(out), poses)
    assert abs(np.median(ratio[np.isfinite(out[..., 0])]) - 1) < 1e-9
    uv_out, _ = project(transform(invert_pose(poses)[None], out[5:]), K)
    np.testing.assert_allclose(uv_out, uv[5:], atol=1e-6)


@pytest.mark.parametrize("keyed", [False, True])
def test_the_bundle_adjustment_draws_tracks_by_their_frames(monkeypatch, keyed):
    """Of a group larger than ``max_fit``, the tracks in the motion's bundle adjustment are drawn with a chance in
    proportion to the frames each is seen in: the long tracks, which tie far-apart frames together, are not left to
    their share of the tracks. The same with a fresh draw and with the tracks' fixed keys."""
    from trackingworld.optim import rigid, stage2

    uv, vis, X, z, poses, K, qf = _scene(rigid=True)
    long = np.arange(len(vis)) < 60  # 10% of the tracks, seen in all 16 frames; the others in 2
    vis = vis.copy()
    vis[~long] = False
    starts = np.random.default_rng(2).integers(0, T - 1, (~long).sum())
    vis[np.flatnonzero(~long)[:, None], starts[:, None] + np.arange(2)] = True
    drawn = []
    real = stage2.BAProblem.from_tracks
    monkeypatch.setattr(stage2.BAProblem, "from_tracks",
                        staticmethod(lambda uv_, d, v, *a: drawn.append(v.sum(1)) or real(uv_, d, v, *a)))
    motion = rigid.fit_motion(uv, vis, z, _lift(uv, z, poses, K), poses, K, OptimConfig(),
                              RigidSettings(max_fit=100), np.random.default_rng(0), iters=1,
                              keys=np.random.default_rng(5).random(len(vis)) if keyed else None)
    assert motion is not None
    share = (drawn[0] == T).mean()  # long tracks among the drawn: 60 * 16 / (60 * 16 + 540 * 2) = 47% of the frames
    assert 0.35 < share < 0.6


def test_a_keyed_draw_is_weighted_and_changes_by_one_track_when_the_set_does():
    """``_draw`` with fixed keys (Efraimidis and Spirakis): each index's chance follows its weight as numpy's
    sequential draw does, and one index more or less in the set changes the draw by at most one index (a fresh
    draw changes most of it), so a group's rounds fit the same tracks and a flipped membership test does not
    redraw the whole fit."""
    from trackingworld.optim.rigid import _draw

    n, k = 400, 100
    idx = np.arange(n)
    weight = np.where(idx < 100, 8.0, 1.0)  # a quarter of the tracks seen 8x as often
    counts = {"keyed": np.zeros(n), "fresh": np.zeros(n)}
    for i in range(300):
        keys = np.random.default_rng(i).random(n)
        d = _draw(idx, weight, k, None, keys)
        assert len(np.unique(d)) == k and (np.diff(d) > 0).all()
        counts["keyed"][d] += 1
        counts["fresh"][_draw(idx, weight, k, np.random.default_rng(1000 + i), None)] += 1
    for c in counts.values():  # the heavy quarter holds the same share of the draws either way
        assert 0.5 < c[:100].sum() / c.sum() < 0.8
    assert abs(counts["keyed"][:100].mean() - counts["fresh"][:100].mean()) < 0.05 * counts["fresh"][:100].mean()
    keys = np.random.default_rng(7).random(n)
    base = _draw(idx, weight, k, None, keys)
    for out in (base[0], base[-1], int(np.setdiff1d(idx, base)[0])):  # one member of the set removed
        keep = idx != out
        d = _draw(idx[keep], weight[keep], k, None, keys[keep])
        assert len(np.setdiff1d(base, d)) <= 1
    fresh = [_draw(idx[idx != j], weight[idx != j], k, np.random.default_rng(0), None) for j in (0, 399)]
    assert len(np.setdiff1d(fresh[0], fresh[1])) > 10


def test_the_second_pass_reaches_a_mover_whose_tracks_are_shorter_than_the_failed_seeds():
    """Long tracks that no rigid motion explains are tried first (the longest remaining track seeds) and use up the
    first pass's failures; the second pass keeps its seeds away from every patch tried, so it reaches the rigid
    mover."""
    uv0, vis0, _, z0, poses, K, qf0 = _scene(rigid=False)
    uv1, vis1, X1, z1, _, _, _ = _scene(rigid=True, seed=1)
    uv1 = uv1 + np.array([120.0, 0.0])  # beside the wandering one in the image
    vis1 = vis1.copy()
    vis1[:, 12:] = False  # seen in 12 frames, the others in all 16
    uv, vis, z = np.r_[uv0, uv1], np.r_[vis0, vis1], np.r_[z0, z1]
    qf = np.r_[qf0, np.random.default_rng(2).integers(0, 12, len(uv1))]
    start = _lift(uv, z * 1.05, poses, K)
    rigid = np.r_[np.zeros(len(uv0), bool), np.ones(len(uv1), bool)]
    for more, found in ((0, False), (30, True)):  # the wandering tracks take the first pass's 8 seeds
        s = RigidSettings(max_failed=8, ring_seeds=more)
        _, groups, _, info = rigid_movers(uv, vis, z * 1.05, start, poses, K, qf, OptimConfig(), s)
        assert ((groups[rigid] >= 0).mean() > 0.75) == found, (more, info)
        assert (groups[~rigid] < 0).mean() > 0.9


def test_a_negative_second_pass_is_refused_in_one_line():
    from trackingworld.errors import InputError
    from trackingworld.pipeline.world import check_optim

    with pytest.raises(InputError, match="rigid_second_pass -1: the seeds are 0 \\(one pass\\) or more"):
        check_optim(OptimConfig(rigid_second_pass=-1))
    check_optim(OptimConfig(rigid_second_pass=0))


def test_the_motion_that_places_a_group_is_fitted_to_that_group(monkeypatch):
    """The rounds' short fits can end on a group that the full fit then grows much larger; its motion, fitted to part
    of the object, places the rest. ``final_rounds`` fits it again to the grown group until that settles."""
    from trackingworld.optim import rigid

    uv, vis, X, z, poses, K, qf = _scene(rigid=True)
    rng = np.random.default_rng(3)
    target = z * (1 + 0.06 * (W / 2 - uv[..., 0]) / (W / 2)) * (1 + 0.01 * rng.standard_normal(z.shape))
    uv = uv + 0.2 * rng.standard_normal(uv.shape)  # a prior warped across the image, 2D noise of 0.2 px
    start = _lift(uv, target, poses, K)
    events = []
    real = rigid.fit_motion
    monkeypatch.setattr(rigid, "fit_motion", lambda *a, **kw: (  # the full fits only (the rounds' pass iters)
        (a[11] if len(a) > 11 else kw.get("iters")) is None and events.append(("fit", len(a[0])))) or real(*a, **kw))
    gaps = {}
    for final in (0, 3):
        events.clear()
        s = RigidSettings(final_rounds=final, rounds=1, round_iters=1, seed_tracks=60, min_tracks=50)
        out, groups, _, info = rigid_movers(uv, vis, target, start, poses, K, qf, OptimConfig(), s,
                                         log=lambda m: events.append(("group", int(m.split()[2]))))
        assert info["rigid_groups"] >= 2 and np.isfinite(out).all()
        fitted = [next(n for kind, n in events[:i][::-1] if kind == "fit")
                  for i, (kind, _) in enumerate(events) if kind == "group"]
        sizes = [n for kind, n in events if kind == "group"]
        gaps[final] = max(abs(n - f) / f for n, f in zip(sizes, fitted, strict=True))
    assert gaps[0] > 0.1  # the case arises without the final rounds ...
    assert gaps[3] <= s.settle  # ... and with them each group's motion is fitted to it


def test_the_rigid_step_reads_the_visible_frames_only_and_writes_into_the_carried_positions():
    """What lets the carrying of the hidden frames run beside it (pipeline.dynamic.place_rigid): positions at the
    hidden frames that differ change nothing the step finds, and its groups land in the array ``into`` gives."""
    uv, vis, X, z, poses, K, qf = _scene(rigid=True, seed=2)
    rng = np.random.default_rng(3)
    vis = rng.random(vis.shape) < 0.8
    vis[np.arange(len(qf)), qf] = True  # seen in their query frames, as dense tracks are
    target = z * 1.04
    carried = _lift(uv, target, poses, K)  # the hidden frames as a carrying would leave them
    before = carried.copy()
    before[~vis] = 7.0  # ... and as they are before it
    ref, groups, _, info = rigid_movers(uv, vis, target, carried, poses, K, qf, OptimConfig(), RigidSettings())
    out, groups2, _, info2 = rigid_movers(uv, vis, target, before, poses, K, qf, OptimConfig(), RigidSettings(),
                                       into=carried.copy)
    assert info["rigid_groups"] >= 1 and info == info2
    np.testing.assert_array_equal(groups, groups2)
    np.testing.assert_array_equal(out, ref)
    from trackingworld.pipeline.dynamic import can_defer_carry

    assert can_defer_carry(vis, qf)
    vis[0, qf[0]] = False
    assert not can_defer_carry(vis, qf)


def test_the_carrying_beside_the_rigid_step_gives_the_result_of_one_after_the_other(tiny_scene, tmp_path,
                                                                                     monkeypatch):
    from trackingworld.cli.main import main
    from trackingworld.io.result import load_result
    from trackingworld.pipeline import dynamic

    inp = tiny_scene / "input"
    args = ["run", str(inp / "frames"), "--depth", str(inp / "depth.npy"), "--masks", str(inp / "masks"),
            "--intrinsics", str(inp / "intrinsics.txt"), "--quiet", "--out"]
    calls = []
    real = dynamic.can_defer_carry
    monkeypatch.setattr(dynamic, "worker_threads", lambda: 2)  # beside it needs two threads (a one-CPU machine: not)
    monkeypatch.setattr(dynamic, "can_defer_carry", lambda *a: calls.append(real(*a)) or calls[-1])
    assert main(args + [str(tmp_path / "beside")]) == 0
    assert calls == [True]
    monkeypatch.setattr(dynamic, "can_defer_carry", lambda *a: False)
    assert main(args + [str(tmp_path / "after")]) == 0
    a, b = load_result(tmp_path / "beside"), load_result(tmp_path / "after")
    np.testing.assert_array_equal(a.is_dynamic, b.is_dynamic)
    np.testing.assert_array_equal(a.visible, b.visible)
    np.testing.assert_allclose(a.tracks_3d, b.tracks_3d, rtol=0, atol=1e-4)  # the run-to-run spread: 1e-4 m


def test_pieces_are_the_points_joined_within_the_gap():
    from trackingworld.optim.rigid import pieces

    rng = np.random.default_rng(0)
    blob = rng.uniform(-0.15, 0.15, (300, 3))
    label = pieces(np.r_[blob, blob[:100] + np.array([1.0, 0.0, 0.0])], gap=0.2)
    assert len(np.unique(label[:300])) == 1 and len(np.unique(label[300:])) == 1 and label[0] != label[-1]
    assert len(np.unique(pieces(blob, gap=0.2))) == 1
    assert len(np.unique(pieces(np.r_[blob, blob[:100] + 0.35], gap=0.2))) == 1  # touching: one piece


def _two_boxes(seed: int, half_gap: float):
    """Two boxes of 150 and 120 points at 3 m, their centres ``2 x half_gap`` apart along x, that move together
    until frame 9, after which the first goes on and the second turns away. Returns the generator, uv, z, true world
    points [N,T,3], poses, K, the first box's tracks [N] bool."""
    rng = np.random.default_rng(seed)
    K, poses = _camera()
    n_a, n_b = 150, 120
    P = rng.uniform(-0.15, 0.15, (n_a + n_b, 3))
    P[:n_a, 0] -= half_gap
    P[n_a:, 0] += half_gap
    t = np.arange(T, dtype=np.float64)
    X = np.repeat(P[:, None], T, 1) + (np.minimum(t, 9)[:, None] * np.array([0.03, 0.0, 0.0]))[None]
    X[:n_a, 10:] += (t[10:] - 9)[None, :, None] * np.array([0.03, 0.0, 0.0])
    X[n_a:, 10:] += (t[10:] - 9)[None, :, None] * np.array([-0.05, 0.03, 0.0])
    uv, z = project(transform(invert_pose(poses)[None], X), K)
    return rng, uv, z, X, poses, K, np.arange(n_a + n_b) < n_a


def _two_objects():
    """Two boxes 1 m apart at 3 m that move together for 10 frames, after which the first (seen in frames 0-9 only)
    goes on and the second (seen in all 16) turns away: one rigid motion explains every track where it is seen.
    Returns uv, vis, true world points [N,T,3], poses, K, query frames, the first box's tracks [N] bool."""
    rng, uv, z, X, poses, K, first = _two_boxes(3, 0.5)
    vis = np.ones(first.shape + (T,), bool)
    vis[first, 10:] = False
    qf = rng.integers(0, 10, len(first))  # both queried where both are seen
    return uv, vis, X, z, poses, K, qf, first


def test_a_group_of_two_objects_one_motion_explains_is_cut_to_its_largest_piece():
    """Without the cut, the second box's turn places the first box in the frames it is hidden in (0.5 m off);
    with it, each box is a group of its own and the first keeps its given positions there."""
    uv, vis, X, z, poses, K, qf, first = _two_objects()
    errs = {}
    for gap in (0.0, 0.1):
        s = RigidSettings(min_tracks=100, split_gap=gap, ring_seeds=0, bridge=None)
        out, groups, _, info = rigid_movers(uv, vis, z, X.copy(), poses, K, qf, OptimConfig(), s)
        b = np.bincount(groups[~first][groups[~first] >= 0]).argmax()  # the second box's group
        assert ((groups[first] == b).mean() > 0.5) == (gap == 0), (gap, info)
        errs[gap] = np.median(np.linalg.norm(out[first][:, 10:] - X[first][:, 10:], axis=-1))
    assert errs[0.0] > 0.2 and errs[0.1] < 0.01, errs


def _handed_over():
    """Two boxes at 3 m, 0.24 m apart (the pieces rule's cubes touch), moving together: the first is seen in frames
    0-9, the second in 7-15, and after frame 9 the first goes on and the second turns away. One rigid motion explains
    every track where it is seen, and in the frames 7-9 both are seen no track is seen on both sides. Returns uv,
    vis, true world points [N,T,3], poses, K, query frames, the first box's tracks [N] bool."""
    rng, uv, z, X, poses, K, first = _two_boxes(5, 0.27)
    vis = np.ones(first.shape + (T,), bool)
    vis[first, 10:] = False
    vis[~first, :7] = False
    # the first box queried in frames 7-9, where both are seen
    qf = np.where(first, rng.integers(7, 10, len(first)), rng.integers(7, T, len(first)))
    return uv, vis, X, z, poses, K, qf, first


def test_a_group_of_two_objects_handed_over_is_cut_to_the_larger():
    """Without the cut the first box follows the second's turn in the frames it is hidden in; with it each box
    has a group of its own, and the first keeps its given positions there. The pieces rule leaves the group whole
    (its cubes touch)."""
    uv, vis, X, z, poses, K, qf, first = _handed_over()
    errs = {}
    for relay in (0.0, 0.05):
        s = RigidSettings(min_tracks=100, relay_gap=relay, ring_seeds=0, bridge=None)
        out, groups, _, info = rigid_movers(uv, vis, z, X.copy(), poses, K, qf, OptimConfig(), s)
        a = np.bincount(groups[first][groups[first] >= 0]).argmax()  # the first box's group
        assert ((groups[~first] == a).mean() > 0.5) == (relay == 0), (relay, info)
        errs[relay] = np.median(np.linalg.norm(out[first][:, 10:] - X[first][:, 10:], axis=-1))
    assert errs[0.0] > 0.2 and errs[0.05] < 0.01, errs


def test_one_object_whose_tracks_were_picked_up_again_is_not_cut():
    """The later tracks on the same surface as the earlier ones: one object, however few tracks span the two."""
    from trackingworld.optim.rigid import handed_over

    uv, vis, X, K, first = _relay_points()
    s = RigidSettings(min_tracks=100)
    R = torch.as_tensor(np.repeat(np.eye(3)[None], T, 0))
    t = torch.as_tensor(np.repeat(np.array([[0.0, 0.0, 3.0]]), T, 0))
    motion = (np.arange(T), R, t)
    rows = np.arange(len(vis))
    early = handed_over(uv, vis, rows, X, motion, K, s, 3.0)
    np.testing.assert_array_equal(early, first)  # 0.5 m apart: two objects, the earlier set marked
    apart = X.copy()
    apart[~first] -= np.array([0.5, 0.0, 0.0])  # the later points on the earlier ones' surface
    uv2 = _project_static(apart, K)
    assert handed_over(uv2, vis, rows, apart, motion, K, s, 3.0) is None
    vis2 = vis.copy()
    vis2[:40] = True  # 40 of the earlier tracks seen throughout: they span the two sets
    assert handed_over(uv, vis2, rows, X, motion, K, s, 3.0) is None


def _project_static(P, K):
    """uv [n,T,2] of object points P [n,3] 3 m ahead of a still camera (the object frame is the camera's)."""
    c = P + np.array([0.0, 0.0, 3.0])
    uv = np.stack([K[0, 0] * c[:, 0] / c[:, 2] + K[0, 2], K[1, 1] * c[:, 1] / c[:, 2] + K[1, 2]], -1)
    return np.repeat(uv[:, None], T, 1)


def _relay_points():
    """Points of an object frame 3 m ahead of a still camera: 150 seen in frames 0-7, 120 in 8-15, the later ones
    0.5 m to the right. Returns uv, vis, the points [n,3], K, the earlier tracks [n] bool."""
    rng = np.random.default_rng(6)
    K, _ = _camera()
    P = rng.uniform(-0.15, 0.15, (270, 3))
    first = np.arange(270) < 150
    P[~first, 0] += 0.5
    vis = np.zeros((270, T), bool)
    vis[first, :8] = True
    vis[~first, 8:] = True
    return _project_static(P, K), vis, P, K, first


def test_a_negative_split_gap_is_refused_in_one_line():
    from trackingworld.errors import InputError
    from trackingworld.pipeline.world import check_optim

    with pytest.raises(InputError, match="rigid_split_gap -0.1: a fraction of the depth"):
        check_optim(OptimConfig(rigid_split_gap=-0.1))
    with pytest.raises(InputError, match="rigid_relay_gap -0.1: a fraction of the depth"):
        check_optim(OptimConfig(rigid_relay_gap=-0.1))
    with pytest.raises(InputError, match="rigid_key_frames 2: 0 .all frames. or 3 or more"):
        check_optim(OptimConfig(rigid_key_frames=2))


def test_float32_tracks_give_the_numbers_of_their_float64_copies():
    # the pipeline hands the step its float32 pixels and positions (20 bytes an observation less than float64
    # copies): every computation reads them in float64, so the result is that of the same values in float64
    uv, vis, X, z, poses, K, qf = _scene(rigid=True)
    uv32 = uv.astype(np.float32)
    start32 = _lift(uv, z * 1.05, poses, K).astype(np.float32)
    out64, g64, m64, i64 = rigid_movers(uv32.astype(np.float64), vis, z * 1.05, start32.astype(np.float64), poses, K,
                                        qf, OptimConfig(), RigidSettings())
    out32, g32, m32, i32 = rigid_movers(uv32, vis, z * 1.05, start32, poses, K, qf, OptimConfig(), RigidSettings())
    assert i64["rigid_groups"] >= 1 and i32 == i64
    assert np.array_equal(g32, g64) and np.array_equal(m32, m64, equal_nan=True)
    assert out32.dtype == np.float32 and np.array_equal(out32, out64.astype(np.float32))


def test_camera_depths_where_indexed_are_those_of_the_whole_array():
    from trackingworld.optim.rigid import CameraDepths

    uv, vis, X, z, poses, K, qf = _scene(rigid=True)
    for xyz in (X, X.astype(np.float32)):
        whole, lazy = camera_depths(xyz, poses), CameraDepths(xyz, poses)
        rows = np.array([5, 0, 599, 5])
        assert np.array_equal(lazy[rows, 3], whole[rows, 3])  # one frame
        assert np.array_equal(lazy[rows, qf[rows]], whole[rows, qf[rows]])  # a frame per track
        assert np.array_equal(lazy[:, 7], whole[:, 7]) and lazy[rows, 3].dtype == np.float64


def test_rows_read_as_the_copied_rows_for_every_index_the_step_uses():
    from trackingworld.optim.rows import Rows

    a = np.arange(7 * 4 * 2, dtype=np.float32).reshape(7, 4, 2)
    rows = np.array([6, 1, 3, 4])
    view, ref = Rows(a, rows), a[rows]
    assert view.shape == ref.shape and view.dtype == ref.dtype and len(view) == 4
    mask = np.array([True, False, True, True])
    for key in (2, np.array([3, 0, 0]), mask, slice(1, 3), (np.array([1, 2]), 3), (mask, slice(None), 1),
                np.ix_(np.array([0, 2]), np.array([1, 3])), (np.array([0, 1]), np.array([2, 3]))):
        assert np.array_equal(view[key], ref[key])
    assert np.array_equal(view.copy(), ref) and np.array_equal(view.of(mask), rows[mask])


def test_tracks_read_in_place_from_every_track_give_the_numbers_of_their_copies():
    # the pipeline hands the step the dynamic tracks as rows of its arrays of every track (Rows), not copies
    from trackingworld.optim.rows import Rows

    uv, vis, X, z, poses, K, qf = _scene(rigid=True)
    start = _lift(uv, z * 1.05, poses, K).astype(np.float32)
    rng = np.random.default_rng(3)
    dyn = np.sort(rng.choice(1000, len(uv), replace=False))  # the mover's rows among 1000 tracks
    all_uv = rng.uniform(0, W, (1000, T, 2)).astype(np.float32)
    all_xyz = rng.normal(0, 1, (1000, T, 3)).astype(np.float32)
    all_uv[dyn], all_xyz[dyn] = uv, start
    ref = rigid_movers(all_uv[dyn], vis, z * 1.05, all_xyz[dyn], poses, K, qf, OptimConfig(), RigidSettings())
    got = rigid_movers(Rows(all_uv, dyn), vis, z * 1.05, Rows(all_xyz, dyn), poses, K, qf, OptimConfig(),
                       RigidSettings())
    assert ref[3]["rigid_groups"] >= 1 and got[3] == ref[3]
    assert np.array_equal(got[0], ref[0]) and np.array_equal(got[1], ref[1])
    assert np.array_equal(got[2], ref[2], equal_nan=True)


def test_key_frames_spread_evenly_and_keep_short_motions_whole():
    from trackingworld.optim.rigid import key_frames

    np.testing.assert_array_equal(key_frames(10, 4), [0, 3, 6, 9])
    np.testing.assert_array_equal(key_frames(48, 48), np.arange(48))
    np.testing.assert_array_equal(key_frames(120, 0), np.arange(120))
    k = key_frames(120, 48)
    assert len(k) == 48 and k[0] == 0 and k[-1] == 119 and np.diff(k).max() <= 3


def test_a_long_motion_is_fitted_on_key_frames_and_its_other_frames_to_their_points(monkeypatch):
    """Beyond ``max_fit_frames`` solved frames the bundle adjustment sees only the key frames (its dense pose system
    grows with the square of the frames); every other frame's pose is fitted to its points, and the motion is that of
    the bundle adjustment over all frames within a millimetre and a hundredth of a degree."""
    from trackingworld.optim import rigid, stage2

    uv, vis, X, z, poses, K, qf = _scene(rigid=True)
    target = z * 1.05 * (1 + 0.02 * np.random.default_rng(1).standard_normal(z.shape))
    start = _lift(uv, target, poses, K)
    frames_seen = []
    real = stage2.BAProblem.from_tracks
    monkeypatch.setattr(stage2.BAProblem, "from_tracks",
                        staticmethod(lambda uv_, d, v, *a: frames_seen.append(v.shape[1]) or real(uv_, d, v, *a)))
    motion = {}
    for cap in (0, 6):
        frames_seen.clear()
        order, R, tr = rigid.fit_motion(uv, vis, target, start, poses, K, OptimConfig(),
                                        RigidSettings(max_fit_frames=cap), np.random.default_rng(0))
        assert sorted(order) == list(range(T)) and order[0] == int(np.argmax(vis.sum(0)))
        assert frames_seen == ([T] if cap == 0 else [6, T - 6])  # the bundle adjustment, then the other frames
        motion[cap] = rigid.motion_poses((order, R, tr), poses, T)
    full, keyed = motion[0], motion[6]
    assert np.abs(keyed[:, :3, 3] - full[:, :3, 3]).max() < 1e-3
    turn = Rotation.from_matrix(keyed[:, :3, :3] @ full[:, :3, :3].transpose(0, 2, 1)).magnitude()
    assert np.rad2deg(turn).max() < 0.01
    # the poses fitted to the points are the fit's: off by what the depth noise makes of the 5% scale, no more
    ratio = np.linalg.norm(keyed[:, :3, 3] - keyed[:1, :3, 3], axis=-1)[1:] / \
        np.linalg.norm(full[:, :3, 3] - full[:1, :3, 3], axis=-1)[1:]
    np.testing.assert_allclose(ratio, 1.0, atol=2e-3)


def test_fit_poses_recovers_every_frame_alone_from_fixed_points():
    """``stage2.fit_poses``: poses started 2 degrees and 5 cm off, fitted to the exact points of the object and their
    exact pixels and depths, come back to the truth; a frame without observations stays where it started."""
    import torch

    from trackingworld.geometry import pose_from_rt, rigid_transform
    from trackingworld.optim import stage2

    uv, vis, X, z, poses, K, qf = _scene(rigid=True)
    vis = vis.copy()
    vis[:, 4] = False
    p = stage2.BAProblem.from_tracks(uv, z, vis, K, OptimConfig(), torch.float64, "cpu")
    # the object frame is the world frame at frame 0: the truth is camera-from-object at each frame
    truth = invert_pose(poses) @ np.stack([rigid_transform(X[:, 0], X[:, t]) for t in range(T)])
    off = np.stack([np.eye(4)] * T)
    off[:, :3, :3] = Rotation.from_rotvec(np.tile([0.0, np.deg2rad(2.0), 0.0], (T, 1))).as_matrix()
    off[:, :3, 3] = 0.05
    start = off @ truth
    R, t = stage2.fit_poses(torch.as_tensor(start[:, :3, :3]), torch.as_tensor(start[:, :3, 3]),
                            torch.as_tensor(X[:, 0]), p)
    got = pose_from_rt(R.numpy(), t.numpy())
    moved = np.arange(T) != 4
    np.testing.assert_allclose(got[moved], truth[moved], atol=1e-6)
    np.testing.assert_allclose(got[4], start[4], atol=1e-9)
