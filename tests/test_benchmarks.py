"""The benchmark scripts refuse a preset the synthetic generator does not know on one line, before any work (they
run on demand, never in the tests; only their command lines are checked here), and the scene cache's code digest
follows the shared modules the tracker imports; the depth-error probe splits an error along and across the ray; the
group-depth probe recovers a mover's true motion and reprojects it."""

import importlib
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture(scope="module", autouse=True)
def _benchmarks_importable():
    sys.path.insert(0, str(BENCH))  # the scripts import their sibling _common
    yield
    sys.path.remove(str(BENCH))


@pytest.mark.parametrize("script", ["bench_device", "bench_focal", "bench_optim", "bench_priors", "bench_scaling",
                                    "bench_solver"])
def test_an_unknown_preset_is_refused_by_argparse(script, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e:
        importlib.import_module(script).main(["--preset", "nope"])
    assert e.value.code == 2
    assert "invalid choice: 'nope'" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())  # no scratch folder, no scene


def test_bench_scenes_refuses_an_unknown_preset(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit, match="unknown preset 'nope'; choose from easy, default, hard"):
        importlib.import_module("bench_scenes").main(["--scenes", "nope:0", "--cache", str(tmp_path / "c")])
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("scene, says", [("nope=1", "'nope' is not a SceneConfig field"),
                                         ("cam_speed=fast", "'fast' is not of type float"),
                                         ("n_clutter=2.5", "'2.5' is not of type int")])
def test_bench_scaling_refuses_a_bad_scene_field(scene, says, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e:
        importlib.import_module("bench_scaling").main(["--scene", scene])
    assert e.value.code == 2 and says in capsys.readouterr().err


def test_the_cache_digest_follows_the_shared_modules_a_package_imports(tmp_path):
    source_digest = importlib.import_module("bench_scenes").source_digest
    (tmp_path / "tracker").mkdir()
    (tmp_path / "tracker" / "flow.py").write_text("from trackingworld.image import sample\n")
    (tmp_path / "image.py").write_text("def sample(): return 1\n")
    (tmp_path / "other.py").write_text("x = 1\n")
    before = source_digest(tmp_path / "tracker")
    (tmp_path / "other.py").write_text("x = 2\n")  # not imported by the package: same digest
    assert source_digest(tmp_path / "tracker") == before
    (tmp_path / "image.py").write_text("def sample(): return 2\n")  # imported: the cached tracks are stale
    assert source_digest(tmp_path / "tracker") != before


def test_the_depth_error_probe_splits_an_error_along_and_across_the_ray():
    import numpy as np

    ray_split = importlib.import_module("probe_depth_error").ray_split
    centres = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]])
    true = np.array([[0.0, 0.0, 5.0], [1.0, 2.0, 13.0]])  # 5 and 10 m straight ahead along z
    along, across, depth = ray_split(true + [[0.0, 0.0, 0.2], [0.0, 0.3, -0.4]], true, centres)
    assert np.allclose(depth, [5.0, 10.0])
    assert np.allclose(along, [0.2, -0.4])  # beyond the point positive, nearer negative
    assert np.allclose(across, [0.0, 0.3])


def test_the_scale_probe_makes_true_static_tracks_with_noise_off_their_query_frame(tiny_scene):
    import numpy as np

    from trackingworld.eval.evaluate import load_gt
    from trackingworld.geometry import invert_pose, transform, unproject

    probe = importlib.import_module("probe_ba_scale")
    gt = load_gt(tiny_scene, 10)
    exact, vis, q = probe.true_static_tracks(gt, 8, 5, 0.0, np.random.default_rng(0))
    n = np.arange(len(q))
    qf, x, y = q[:, 0].astype(int), q[:, 1].astype(int), q[:, 2].astype(int)
    assert len(q) > 100 and set(qf) == {0, 5} and vis[n, qf].all() and (vis.sum(1) >= 2).mean() > 0.8
    np.testing.assert_array_equal(exact[n, qf], q[:, 1:])  # they start on the grid
    assert not gt["dynamic"][qf, y, x].any()  # on the static background
    # seen where the true depth at the projection is the point's own camera depth
    K = gt["K"].astype(np.float64)
    cam = unproject(q[:, 1:].astype(np.float64), gt["depth"][qf, y, x].astype(np.float64), K)
    world = np.stack([transform(gt["poses_c2w"][f], c[None])[0] for f, c in zip(qf, cam, strict=True)])
    t = 7
    s = np.flatnonzero(vis[:, t])
    z = transform(invert_pose(gt["poses_c2w"][t]), world[s])[:, 2]
    xi, yi = np.round(exact[s, t]).astype(int).T
    assert (np.abs(gt["depth"][t, yi, xi] / z - 1) < probe.VISIBLE_DEPTH_TOL).all()
    noisy, vis2, _ = probe.true_static_tracks(gt, 8, 5, 0.5, np.random.default_rng(0))
    np.testing.assert_array_equal(vis2, vis)
    d = noisy - exact
    np.testing.assert_array_equal(d[n, qf], 0.0)  # the query frame exact
    off = np.ones(vis.shape, bool)
    off[n, qf] = False
    assert 0.45 < d[off].std() < 0.55 and abs(d[off].mean()) < 0.02
    poses = gt["poses_c2w"].copy()
    assert probe.path_ratio(poses, gt["poses_c2w"]) == 1.0
    poses[:, :3, 3] *= 1.01
    assert abs(probe.path_ratio(poses, gt["poses_c2w"]) - 1.01) < 1e-6  # float32 poses


def test_the_group_depth_probe_recovers_a_mover_and_reprojects_its_truth(tiny_scene):
    from types import SimpleNamespace

    import numpy as np

    from trackingworld.eval.evaluate import load_gt
    from trackingworld.geometry import transform

    probe = importlib.import_module("probe_group_depth")
    gt = load_gt(tiny_scene, 10)
    start = importlib.import_module("_common").query_objects(gt)
    obj = int(np.bincount(start[gt["tracks_dynamic"]]).argmax())  # the mover with the most queries
    on = np.flatnonzero(start == obj)
    motion = probe.true_motion(gt, obj)
    X = gt["tracks_xyz"][on]
    for t in (3, 9):  # the object's queries follow its motion from frame 0
        assert np.abs(transform(motion[t], X[:, 0]) - X[:, t]).max() < 1e-4
    assert np.abs(transform(motion[9], X[:, 0]) - X[:, 0]).max() > 0.05  # and it moves
    assert probe.true_motion(gt, -5) is None
    # a result whose tracks are the ground truth's: both the fitted positions and the truth reproject onto them
    res = SimpleNamespace(intrinsics=gt["K"], poses_c2w=gt["poses_c2w"], query_frame=gt["query_frame"][on],
                          tracks_2d=gt["tracks_uv"][on], tracks_3d=X, visible=gt["tracks_vis"][on].astype(bool))
    fit_px, truth_px = probe.reprojection(res, gt, np.arange(len(on)), motion)
    assert fit_px < 0.05 and truth_px < 0.3  # the truth reads the depth at the query's nearest pixel
    res.tracks_2d = res.tracks_2d + np.arange(10)[None, :, None] * 0.5  # 2D tracks drifting 0.5 px a frame
    fit_px2, truth_px2 = probe.reprojection(res, gt, np.arange(len(on)), motion)
    assert fit_px2 > 1.0 and truth_px2 > 1.0
    assert probe.reprojection(res, gt, np.arange(len(on)), None)[1] is None
