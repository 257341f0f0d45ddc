import json

import imageio.v3 as iio
import numpy as np
import pytest

from trackingworld.geometry import invert_pose, project, transform


def test_scene_files_and_shapes(tiny_scene):
    inp = tiny_scene / "input"
    assert len(list((inp / "frames").glob("*.png"))) == 10
    assert len(list((inp / "masks").glob("*.png"))) == 10
    depth = np.load(inp / "depth.npy")
    assert depth.shape == (10, 96, 128) and depth.dtype == np.float32
    K = np.loadtxt(inp / "intrinsics.txt")
    assert K.shape == (3, 3)
    frame = iio.imread(inp / "frames" / "00000.png")
    assert frame.shape == (96, 128, 3) and frame.std() > 10  # textured, not flat


def test_ground_truth_is_consistent(tiny_scene):
    g = np.load(tiny_scene / "gt.npz")
    N, T = g["tracks_vis"].shape
    qf = g["query_frame"]
    # at its query frame, a track is visible, sits on the query pixel and has the rendered depth
    np.testing.assert_allclose(g["tracks_uv"][np.arange(N), qf], g["query_uv"], atol=1e-3)
    assert g["tracks_vis"][np.arange(N), qf].all()
    # the world points project to the stored pixels in every frame
    cam = transform(invert_pose(g["poses_c2w"].astype(np.float64))[None], g["tracks_xyz"].astype(np.float64))
    uv, z = project(cam, g["K"].astype(np.float64))
    np.testing.assert_allclose(uv, g["tracks_uv"], atol=1e-2)
    qx, qy = g["query_uv"][:, 0].astype(int), g["query_uv"][:, 1].astype(int)
    np.testing.assert_allclose(z[np.arange(N), qf], g["depth"][qf, qy, qx], rtol=1e-4)
    # static tracks do not move in the world; dynamic ones do
    motion = np.linalg.norm(g["tracks_xyz"] - g["tracks_xyz"][:, :1], axis=-1).max(1)
    assert motion[~g["tracks_dynamic"]].max() < 1e-5
    assert np.median(motion[g["tracks_dynamic"]]) > 0.05
    # some tracks get occluded or leave the view
    assert 0.2 < g["tracks_vis"].mean() < 0.98


def test_scene_has_the_hard_cases(tiny_scene):
    g = np.load(tiny_scene / "gt.npz")
    objs = json.loads((tiny_scene / "scene.json").read_text())["objects"]
    inst = g["instance"]
    entering = [i for i, o in enumerate(objs) if o["name"] == "entering"][0]
    assert (inst[0] == entering).sum() == 0 and (inst[-1] == entering).sum() > 0
    masks = np.stack([iio.imread(tiny_scene / "input" / "masks" / f"{t:05d}.png") for t in range(10)]) > 0
    assert g["bg_mover"].any()
    # the background mover is (mostly) missing from the coarse masks; masked movers are covered
    assert (masks & g["bg_mover"]).sum() < 0.2 * g["bg_mover"].sum()
    masked_movers = g["dynamic"] & ~g["bg_mover"]
    assert (masks & masked_movers).sum() > 0.95 * masked_movers.sum()


def test_depth_prior_is_corrupted_but_close(tiny_scene):
    g = np.load(tiny_scene / "gt.npz")
    prior = np.load(tiny_scene / "input" / "depth.npy")
    rel = np.abs(prior - g["depth"]) / g["depth"]
    assert 0.01 < np.median(rel) < 0.3


def test_seed_determinism(tmp_path):
    from trackingworld.synth import render_and_write

    a = render_and_write(tmp_path / "a", "easy", seed=5, frames=3, size=(48, 32), verbose=False)
    b = render_and_write(tmp_path / "b", "easy", seed=5, frames=3, size=(48, 32), verbose=False)
    np.testing.assert_array_equal(np.load(a / "input" / "depth.npy"), np.load(b / "input" / "depth.npy"))


def test_a_camera_path_that_leaves_the_room_is_refused(tmp_path, capsys):
    """240 frames at the default speed walk the camera out through a wall: refused on one line before anything is
    written; at half the speed the same length stays inside."""
    from trackingworld.cli.main import main
    from trackingworld.synth.scene import make_scene

    assert main(["synth", str(tmp_path / "s"), "--frames", "240", "--size", "32x24"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "leaves the room at frame" in err[0] and "cam_speed" in err[0]
    assert not (tmp_path / "s").exists()
    scene = make_scene("default", 0, frames=240, cam_speed=0.025)
    lo, hi = np.array([-4.5, -2.2, -3.0]), np.array([4.5, 1.3, 9.0])
    eyes = scene.poses_c2w[:, :3, 3]
    assert ((eyes > lo) & (eyes < hi)).all()


def test_movers_turn_back_before_they_leave_the_room():
    from trackingworld.synth.scene import _bounce, make_scene

    lo, hi = np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0])
    c = np.array([[0.3, -0.2, 0.9], [1.5, 0.0, 0.0], [-3.5, 0.0, 0.0], [5.2, 0.0, 0.0]])
    # inside: the very same numbers; outside: reflected at the bound, as often as it takes
    np.testing.assert_array_equal(_bounce(c, lo, hi)[0], c[0])
    np.testing.assert_allclose(_bounce(c, lo, hi)[1:, 0], [0.5, 0.5, 0.8])
    # a 120-frame default scene whose movers, on straight paths, leave the room (seed 1: three of them)
    room_lo, room_hi = np.array([-4.5, -2.2, -3.0]), np.array([4.5, 1.3, 9.0])
    sc = make_scene("default", 1, frames=120)
    movers = [p for p in sc.prims if p.moving]
    for p in movers:
        reach = p.size.max()
        c = p.poses[:, :3, 3]
        assert np.all((c >= room_lo - reach - 1e-9) & (c <= room_hi + reach + 1e-9)), p.name
    # and they still move with the speed they were given
    steps = np.linalg.norm(np.diff(movers[0].poses[:, :3, 3], axis=0), axis=1)
    assert np.median(steps) == pytest.approx(sc.config.mover_speed, rel=1e-6)


def test_grounded_movers_stand_on_the_floor():
    """``grounded_movers``: every mover's lowest point is on the floor in every frame, it moves only horizontally
    and boxes stay level; the camera path and the static primitives are the floating scene's (the same draws)."""
    from trackingworld.synth.scene import BOX, SPHERE, make_scene

    floor_y = 1.3
    a, b = make_scene("default", 3), make_scene("default", 3, grounded_movers=True)
    np.testing.assert_array_equal(a.poses_c2w, b.poses_c2w)
    assert [p.name for p in a.prims] == [p.name for p in b.prims]
    for pa, pb in zip(a.prims, b.prims, strict=True):
        np.testing.assert_array_equal(pa.size, pb.size)
        if not pb.moving:
            np.testing.assert_array_equal(pa.poses, pb.poses)
            continue
        c = pb.poses[:, :3, 3]
        half = pb.size[0] if pb.kind == SPHERE else pb.size[1]
        np.testing.assert_allclose(c[:, 1] + half, floor_y, atol=1e-9)
        assert np.linalg.norm(np.diff(c[:, [0, 2]], axis=0), axis=1).min() > 0  # it still moves
        if pb.kind == BOX:  # level: the box's own y axis stays vertical
            np.testing.assert_allclose(pb.poses[:, :3, 1], np.tile([0.0, 1.0, 0.0], (len(c), 1)), atol=1e-9)
    # the floating scene's movers are not on the floor
    assert any(abs(p.poses[0, 1, 3] + (p.size[0] if p.kind == SPHERE else p.size[1]) - floor_y) > 0.1
               for p in a.prims if p.moving)


def test_synth_grounded_flag(tmp_path):
    import json

    from trackingworld.cli.main import main

    assert main(["synth", str(tmp_path / "g"), "--grounded", "--frames", "2", "--size", "32x24"]) == 0
    assert json.loads((tmp_path / "g" / "scene.json").read_text())["config"]["grounded_movers"] is True
    assert main(["synth", str(tmp_path / "f"), "--frames", "2", "--size", "32x24"]) == 0
    assert json.loads((tmp_path / "f" / "scene.json").read_text())["config"]["grounded_movers"] is False
