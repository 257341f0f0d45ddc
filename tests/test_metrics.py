"""Every metric on hand-made cases with known answers."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from trackingworld.eval.dense import coverage, flow_metrics, label_metrics, static_deviation, track_depth_maps
from trackingworld.eval.depth import abs_rel_delta1, depth_metrics, fit_scale_shift_depth
from trackingworld.eval.match import match_queries
from trackingworld.eval.tracks import tapvid_2d, tapvid_3d, world_accuracy
from trackingworld.eval.trajectory import apply_sim3, camera_metrics, sim3_from_poses, sim3_from_trajectories
from trackingworld.geometry import pose_from_rt


def circle_traj(T=20):
    t = np.linspace(0, np.pi, T)
    R = Rotation.from_euler("y", (t * 30)[:, None], degrees=True).as_matrix()
    pos = np.stack([np.cos(t), 0.1 * t, np.sin(t)], 1) * 2
    return pose_from_rt(R, pos)


def test_ate_zero_for_scaled_rotated_copy():
    gt = circle_traj()
    S = pose_from_rt(Rotation.from_euler("xyz", [10, 40, -20], degrees=True).as_matrix(), np.array([1.0, -2, 3]))
    est = S @ gt
    est[:, :3, 3] *= 0.37  # a different world scale
    m = camera_metrics(est, gt)
    assert m["alignment"] == "sim3_umeyama"
    assert m["ate"] < 1e-6 and m["rte"] < 1e-6 and m["rre"] < 1e-4
    assert m["scale"] == pytest.approx(1 / 0.37, rel=1e-5)


def test_ate_known_offset():
    # est = gt with alternating +-d offsets along x: Sim(3) cannot remove it; ATE = d (RMSE)
    gt = circle_traj(40)
    gt[:, :3, :3] = np.eye(3)
    gt[:, 1, 3] = 0.0  # a planar path in x-z
    est = gt.copy()
    d = 0.05
    est[:, 1, 3] += d * np.where(np.arange(40) % 2 == 0, 1, -1)  # alternating, out of the plane
    m = camera_metrics(est, gt)
    assert m["ate"] == pytest.approx(d, rel=0.02)
    # consecutive relative translations differ by 2d in x, rotations are exact
    assert m["rte"] == pytest.approx(2 * d, rel=0.05)
    assert m["rre"] < 1e-6


def test_rre_known_rotation_error():
    gt = circle_traj(30)
    est = gt.copy()
    # every odd frame rotated by 1 degree about z: each consecutive pair is off by 1 degree
    Rz = Rotation.from_euler("z", 1, degrees=True).as_matrix()
    est[1::2, :3, :3] = est[1::2, :3, :3] @ Rz
    m = camera_metrics(est, gt)
    assert m["rre"] == pytest.approx(1.0, abs=0.02)


def test_static_trajectory_is_reported_not_crashing():
    gt = circle_traj()
    est = np.tile(np.eye(4), (len(gt), 1, 1))
    m = camera_metrics(est, gt)
    assert m["alignment"] == "first_frame_se3" and "note" in m
    assert np.isfinite(m["ate"])


def test_sim3_maps_points():
    gt = circle_traj()
    S = pose_from_rt(Rotation.from_euler("y", 70, degrees=True).as_matrix(), np.array([3.0, 0, 1]))
    est = S @ gt
    al = sim3_from_trajectories(est, gt)
    p_gt = np.array([[0.5, 0.2, 3.0]])
    p_est = (np.linalg.inv(S)[:3, :3] @ p_gt.T).T + np.linalg.inv(S)[:3, 3]
    p_est = (S[:3, :3] @ p_gt.T).T + S[:3, 3]  # points move with the world like the cameras do
    np.testing.assert_allclose(apply_sim3(al, p_est), p_gt, atol=1e-6)


def test_sim3_from_poses_exact_and_well_posed_on_a_straight_path(rng):
    # exact: a scaled, rotated, moved copy of a trajectory is mapped back
    gt = circle_traj()
    S = pose_from_rt(Rotation.from_euler("xyz", [10, 40, -20], degrees=True).as_matrix(), np.array([1.0, -2, 3]))
    est = S @ gt
    est[:, :3, 3] *= 0.37
    al = sim3_from_poses(est, gt)
    assert al["mode"] == "sim3_poses" and al["s"] == pytest.approx(1 / 0.37, rel=1e-6)
    np.testing.assert_allclose(apply_sim3(al, est), gt, atol=1e-6)
    # a forward camera on a nearly straight path (2 cm of sideways wiggle over 4 m), centres off by 5 mm noise,
    # orientations exact: the centres alone leave the tilt about the path loose, the poses fix it; a point
    # 7 m to the side shows the difference
    T = 40
    z = np.linspace(0, 4, T)
    pos = np.stack([0.02 * np.sin(z * 3), np.zeros(T), z], 1)
    gt = pose_from_rt(np.tile(np.eye(3), (T, 1, 1)), pos)
    est = gt.copy()
    est[:, :3, 3] += 0.005 * rng.standard_normal((T, 3))
    p = np.array([[7.0, 0.0, 2.0]])
    err_c = np.linalg.norm(apply_sim3(sim3_from_trajectories(est, gt), p) - p)
    err_p = np.linalg.norm(apply_sim3(sim3_from_poses(est, gt), p) - p)
    assert err_p < 0.02 and err_c > 3 * err_p


def test_depth_scale_shift_invariance(rng):
    gt = rng.uniform(1, 10, size=(4, 20, 30))
    pred = 0.5 * gt + 0.3
    m = depth_metrics(pred, gt)
    assert m["abs_rel_depth"] < 1e-6 and m["delta1_depth"] == 1.0
    pred_disp = 1.0 / (2.0 / gt + 0.01)  # affine in disparity
    m = depth_metrics(pred_disp, gt)
    assert m["abs_rel_disparity"] < 1e-6


def test_abs_rel_known_value():
    gt = np.array([1.0, 2.0, 4.0])
    pred = np.array([1.1, 2.0, 4.0])
    ar, d1 = abs_rel_delta1(pred, gt)
    assert ar == pytest.approx(0.1 / 3)
    assert d1 == 1.0
    ar, d1 = abs_rel_delta1(np.array([2.0, 2.0, 4.0]), gt)
    assert d1 == pytest.approx(2 / 3)


def test_l1_fit_ignores_outliers(rng):
    gt = rng.uniform(1, 5, 500)
    pred = gt / 2.0 + 0.1
    gt = gt.copy()
    gt[:20] += 30  # 4% gross outliers in the target (L1 ignores these; least squares would not)
    s, b = fit_scale_shift_depth(pred, gt)
    assert s == pytest.approx(2.0, rel=1e-3) and b == pytest.approx(-0.2, abs=1e-3)


def test_tapvid_2d_known():
    N, T = 4, 5
    gt = np.zeros((N, T, 2))
    vis = np.ones((N, T), bool)
    qf = np.zeros(N, int)
    m = tapvid_2d(gt.copy(), vis, gt, vis, qf, (256, 256))
    assert m["delta_avg"] == 100 and m["occlusion_acc"] == 100
    pred = gt + np.array([3.0, 0])  # 3 px: within 4, 8, 16 only
    m = tapvid_2d(pred, vis, gt, vis, qf, (256, 256))
    assert m["delta_avg"] == pytest.approx(60.0)
    # the same 3 px at 512 wide is 1.5 px at 256: within 2, 4, 8, 16
    m = tapvid_2d(pred, vis, gt, vis, qf, (512, 256))
    assert m["delta_avg"] == pytest.approx(80.0)
    pv = vis.copy()
    pv[:, 1] = False  # one of four evaluated frames predicted occluded wrongly
    assert tapvid_2d(gt, pv, gt, vis, qf, (256, 256))["occlusion_acc"] == pytest.approx(75.0)


def test_tapvid_3d_known():
    N, T = 3, 4
    gt = np.zeros((N, T, 3))
    gt[..., 2] = 5.0
    gt[..., 0] = np.arange(N)[:, None]
    vis = np.ones((N, T), bool)
    K = np.array([[256.0, 0, 127.5], [0, 256.0, 127.5], [0, 0, 1]])
    qf = np.zeros(N, int)
    m = tapvid_3d(gt * 3.0, vis, gt, vis, qf, K, (256, 256))  # global scale removed by median scaling
    assert m["aj"] == pytest.approx(100) and m["apd_3d"] == pytest.approx(100) and m["oa"] == 100
    # offset of 3 px-equivalent at depth 5 (3 * 5 / 256 m): within 4, 8, 16 -> 60
    pred = gt.copy()
    pred[..., 1] += 3 * 5 / 256
    m = tapvid_3d(pred, vis, gt, vis, qf, K, (256, 256))
    assert m["apd_3d"] == pytest.approx(60, abs=1e-6)
    # predicting everything occluded gives AJ 0 and OA 0
    m = tapvid_3d(gt, ~vis, gt, vis, qf, K, (256, 256))
    assert m["aj"] == 0 and m["oa"] == 0


def test_world_accuracy_thresholds():
    gt = np.zeros((1, 6, 3))
    vis = np.ones((1, 6), bool)
    pred = gt.copy()
    pred[0, 1:, 0] = [0.01, 0.07, 0.15, 0.3, 1.0]  # frame 0 is the query frame, not evaluated
    m = world_accuracy(pred, gt, vis, np.array([0]))
    # within 5cm: 1/5, 10: 2/5, 20: 3/5, 40: 4/5, 80: 4/5
    assert m["acc_avg"] == pytest.approx(100 * np.mean([0.2, 0.4, 0.6, 0.8, 0.8]))


def test_coverage_known():
    tracks = np.array([[[0, 0]], [[1, 0]], [[1.2, 0.1]], [[5, 5]]], float)  # 4 tracks, 1 frame, 2x2 image
    vis = np.array([[True], [True], [True], [True]])
    assert coverage(tracks, vis, 2, 2)["coverage"] == pytest.approx(0.5)


def test_flow_metrics_known():
    gt = np.zeros((2, 2, 2))
    pred = gt.copy()
    pred[0, 0] = [3, 4]
    occ_gt = np.array([[True, False], [False, False]])
    occ_pr = np.array([[True, True], [False, False]])
    m = flow_metrics(pred, occ_pr, gt, occ_gt)
    assert m["epe"] == pytest.approx(5 / 4) and m["occ_iou"] == pytest.approx(0.5)


def test_track_depth_keeps_nearest():
    poses = np.tile(np.eye(4), (1, 1, 1))
    tracks_2d = np.array([[[1.0, 1.0]], [[1.2, 0.9]], [[0.0, 0.0]]])
    tracks_3d = np.array([[[0, 0, 5.0]], [[0, 0, 3.0]], [[0, 0, 2.0]]])
    vis = np.array([[True], [True], [False]])
    d, hit = track_depth_maps(tracks_2d, vis, tracks_3d, poses, 3, 3)
    assert hit.sum() == 1 and d[0, 1, 1] == 3.0


def test_label_metrics_known():
    pred = np.array([1, 1, 0, 0, 1], bool)
    gt = np.array([1, 0, 1, 0, 1], bool)
    bg = np.array([0, 0, 1, 0, 1], bool)
    m = label_metrics(pred, gt, bg)
    assert m["dynamic_recall"] == pytest.approx(200 / 3)
    assert m["dynamic_precision"] == pytest.approx(200 / 3)
    assert m["static_kept_static"] == pytest.approx(50)
    assert m["bg_mover_recall"] == pytest.approx(50)


def test_static_deviation_separates_slipped_and_moving_tracks_from_static_ones():
    from trackingworld.geometry import look_at, project, transform, unproject

    T, H, W = 4, 60, 80
    K = np.array([[70.0, 0, 40], [0, 70.0, 30], [0, 0, 1]])
    poses = np.stack([look_at(np.array([0.1 * t, 0, 0]), np.array([0.1 * t, 0, 5.0])) for t in range(T)])
    depth = np.full((T, H, W), 5.0)  # a wall 5 m ahead
    q = np.array([[20.0, 30.0], [40.0, 30.0], [60.0, 25.0]])
    X = transform(poses[0], unproject(q, np.full(3, 5.0), K))
    uv = np.stack([project(transform(np.linalg.inv(poses[t]), X), K)[0] for t in range(T)], 1)  # [3,T,2]
    uv[1, 2:] += [3.0, 0.0]  # slipped 3 px from frame 2 on
    uv[2] += np.arange(T)[:, None] * [5.0, 0.0]  # a mover drifting 5 px per frame
    vis = np.ones((3, T), bool)
    vis[2, 3] = False  # its last frame is hidden: only visible frames count
    dev = static_deviation(uv, vis, np.zeros(3, int), depth, poses, K)
    np.testing.assert_allclose(dev, [0.0, 3.0, 10.0], atol=1e-6)
    m = label_metrics(np.array([False, True, True]), np.array([False, False, True]), np.array([False, False, True]),
                      dev)
    assert m["static_kept_static"] == pytest.approx(50) and m["static_consistent_pct"] == pytest.approx(50)
    assert m["static_kept_static_consistent"] == pytest.approx(100)
    assert m["bg_mover_moved_pct"] == pytest.approx(100) and m["bg_mover_recall_moved"] == pytest.approx(100)


def test_match_queries_exact_track():
    T = 3
    tracks = np.array([[[10, 10], [11, 10], [12, 10]], [[40, 40], [40, 41], [40, 42]]], float)
    xyz = np.arange(2 * T * 3, dtype=float).reshape(2, T, 3)
    vis = np.ones((2, T), bool)
    m = match_queries(tracks, vis, xyz, np.array([False, True]), np.array([0, 1]),
                      np.array([[10.0, 10.0], [40.0, 41.0]]), k=1)
    np.testing.assert_allclose(m.uv, tracks)
    np.testing.assert_allclose(m.xyz, xyz)
    assert m.found.all() and list(m.is_dynamic) == [False, True]
