"""Display helpers, the software renderer, ``render`` outputs and the viewer's server side."""

import socket

import numpy as np
import pytest

from exact_result import exact_result, write_exact_result
from trackingworld.cli.main import main
from trackingworld.geometry import default_intrinsics, look_at
from trackingworld.io.result import Result
from trackingworld.optim.label_steps import LABEL_STEPS
from trackingworld.viz import display as D
from trackingworld.viz.splat import orbit_poses, splat


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_subsets_are_nested_and_stable():
    order = D.display_order(1000, seed=3)
    keep = np.arange(1000) % 3 == 0
    small, big = D.first_k(order, keep, 50), D.first_k(order, keep, 200)
    np.testing.assert_array_equal(big[:50], small)
    assert keep[big].all() and len(np.unique(big)) == 200


def test_trail_segments_fade_toward_the_past():
    xyz = np.cumsum(np.ones((3, 10, 3)), axis=1)
    seg, fade = D.trail_segments(xyz, np.array([0, 2]), t=6, length=4)
    assert seg.shape == (8, 2, 3) and fade.shape == (8,)
    np.testing.assert_allclose(seg[3, 1], xyz[0, 6])  # newest segment ends at the current frame
    assert fade[3] == 1.0 and fade[0] == pytest.approx(0.25)
    assert D.trail_segments(xyz, np.array([0]), t=0, length=4)[0].shape == (0, 2, 3)


def test_point_colours_by_mode():
    res, frames = exact_result()
    idx = np.flatnonzero(res.visible[:, 2])
    lab = D.point_colors("label", idx, 2, tracks_2d=res.tracks_2d, is_dynamic=res.is_dynamic, colors=res.colors)
    np.testing.assert_array_equal(lab[res.is_dynamic[idx]][0], D.DYNAMIC_COLOR)
    vid = D.point_colors("video", idx, 2, tracks_2d=res.tracks_2d, is_dynamic=res.is_dynamic, colors=res.colors,
                         frame=frames[2])
    dyn = res.is_dynamic[idx]
    assert np.abs(vid[dyn].astype(int) - [230, 60, 40]).mean() < 30  # the red cube samples red
    with pytest.raises(ValueError):
        D.point_colors("nope", idx, 2, tracks_2d=res.tracks_2d, is_dynamic=res.is_dynamic, colors=res.colors)


def test_splat_projects_and_keeps_the_nearest():
    K = default_intrinsics(40, 30, 60.0)
    pose = look_at(np.zeros(3), np.array([0.0, 0.0, 1.0]))
    pts = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 4.0], [0.0, 0.0, -1.0]])
    img = splat(pts, np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255]], np.uint8), pose, K, (40, 30), radius=0)
    u, v = int(round(K[0, 2])), int(round(K[1, 2]))
    np.testing.assert_array_equal(img[v, u], [255, 0, 0])  # nearer red hides green; blue is behind the camera
    assert (img.reshape(-1, 3) != 255).any(1).sum() == 1
    P = orbit_poses(pose[None], np.array([0.0, 0.0, 3.0]), 3.0, 8)
    assert np.allclose(np.linalg.norm(P[:, :3, 3] - [0, 0, 3], axis=1), 3.0)


def test_render_writes_videos_and_plot_that_are_not_blank(tmp_path):
    import imageio.v3 as iio
    from PIL import Image

    res, frames = write_exact_result(tmp_path)
    assert main(["render", str(tmp_path), "--quiet", "--view", "orbit"]) == 0
    out = tmp_path / "render"
    v2d = iio.imread(out / "tracks_2d.mp4", plugin="pyav")
    v3d = iio.imread(out / "scene_3d.mp4", plugin="pyav")
    assert v2d.shape[0] == res.num_frames and v3d.shape[0] == res.num_frames
    assert v2d.shape[1:3] == (64, 96)
    # drawn tracks: saturated depth colours that the darkened input frame does not have
    assert (v2d[-1].max(-1).astype(int) - v2d[-1].min(-1) > 120).mean() > 0.02
    for v in (v2d, v3d):
        assert v.std() > 10
    assert np.abs(v3d[0].astype(int) - v3d[-1]).mean() > 1  # the view orbits and the cube moves
    png = np.asarray(Image.open(out / "camera_path.png"))
    assert png.shape[0] > 200 and png.std() > 5
    # a fixed viewpoint: the static wall stays put, only the mover and the drawn camera change
    assert main(["render", str(tmp_path), "--quiet", "--only", "scene", "--view", "fixed", "--eye", "0,-1,-3"]) == 0
    fixed = iio.imread(out / "scene_3d.mp4", plugin="pyav").astype(int)
    top = slice(0, fixed.shape[1] // 3)  # the upper wall, away from the cube and the camera
    assert np.abs(fixed[0, top] - fixed[-1, top]).mean() < np.abs(v3d[0, top].astype(int) - v3d[-1, top]).mean()
    assert main(["render", str(tmp_path), "--quiet", "--view", "fixed"]) == 2  # --eye missing: one-line error
    assert main(["view", str(tmp_path / "missing")]) == 2  # no result there: one-line error, no server started


def test_camera_path_plot_against_ground_truth(tmp_path):
    from trackingworld.viz.plots import plot_camera_path

    res, _ = exact_result()
    gt = res.poses_c2w.astype(np.float64).copy()
    gt[:, :3, 3] *= 2.0  # a different scale: the Sim(3) alignment takes it out
    info = plot_camera_path(res.poses_c2w, tmp_path / "p.png", gt)
    assert info["ate"] < 1e-5 and (tmp_path / "p.png").stat().st_size > 10_000
    gt[3, :3, 3] += 0.5
    assert plot_camera_path(res.poses_c2w, tmp_path / "p.png", gt)["ate"] > 0.05


def test_viewer_server_side(tmp_path):
    pytest.importorskip("viser")
    from trackingworld.viz.viewer import Viewer

    res, frames = exact_result()
    v = Viewer(res, frames, port=free_port(), verbose=False)
    try:
        n0 = len(v.points.points)
        assert n0 == int(res.visible[:, 0].sum())
        v.slider.value = 5  # what the browser's slider does
        assert v.t == 5
        np.testing.assert_allclose(v.points.points, res.tracks_3d[v.frame_data(5)[0], 5], atol=1e-2)
        v.density.value = 0.25
        assert len(v.points.points) == pytest.approx(0.25 * min(v.cfg.max_points, res.visible[:, 5].sum()), abs=2)
        v.layers["static map"].value = False
        assert not v.static.visible
        v.color_mode.value = "label"
        assert (v.points.colors == D.DYNAMIC_COLOR).all(1).sum() == int(res.is_dynamic[v.frame_data(5)[0]].sum())
        assert v.trails is not None and len(v.trail_idx) == int(res.is_dynamic.sum())
        v.color_mode.value = "label step"  # this result has no label_step: said in the panel
        assert "no label_step" in v.info.content
        v.color_mode.value = "object"  # ... nor object_id
        assert "no object_id" in v.info.content
    finally:
        v.stop()
    ids = np.where(res.is_dynamic, 0, -1).astype(np.int32)  # every dynamic track one object
    obj = Result(**{**res.as_dict(), "object_id": ids,
                    "object_poses": np.tile(np.eye(4, dtype=np.float32), (1, res.num_frames, 1, 1))})
    v = Viewer(obj, frames, port=free_port(), verbose=False)
    try:
        v.color_mode.value = "object"
        assert "1 rigid object," in v.info.content
        idx = v.frame_data(0)[0]
        assert (v.points.colors == D.OBJECT_COLORS[0]).all(1).sum() == int(obj.is_dynamic[idx].sum()) > 0
    finally:
        v.stop()


def test_points_coloured_by_the_step_that_set_their_label():
    res, _ = exact_result()
    idx = np.flatnonzero(res.visible[:, 2])
    # a result without label_step: the label colours
    plain = D.point_colors("label step", idx, 2, tracks_2d=res.tracks_2d, is_dynamic=res.is_dynamic,
                           colors=res.colors, label_step=res.label_step)
    np.testing.assert_array_equal(plain, D.point_colors("label", idx, 2, tracks_2d=res.tracks_2d,
                                                        is_dynamic=res.is_dynamic, colors=res.colors))
    steps = np.zeros(res.num_tracks, np.int8)
    steps[idx[:3]] = LABEL_STEPS.index("depth_movers")
    steps[idx[3:5]] = LABEL_STEPS.index("photo_static")
    res = Result(**{**res.as_dict(), "label_step": steps})
    _, _, col = D.frame_points(res, 2, idx, len(idx), "label step")  # idx as the order: every visible track
    np.testing.assert_array_equal(col[:3], np.tile(D.STEP_COLORS["depth_movers"][0], (3, 1)))
    np.testing.assert_array_equal(col[3:5], np.tile(D.STEP_COLORS["photo_static"][0], (2, 1)))
    untouched = np.where(res.is_dynamic[idx[5:]][:, None], D.DYNAMIC_COLOR, D.STATIC_COLOR)
    np.testing.assert_array_equal(col[5:], untouched)
    assert "depth_movers: pink" in D.step_legend()


def test_tracks_video_coloured_by_label_step():
    from trackingworld.errors import InputError
    from trackingworld.viz.render import RenderConfig, tracks_video_frames

    res, frames = exact_result()
    with pytest.raises(InputError, match="no label_step"):
        next(tracks_video_frames(res, frames, RenderConfig(color_by="step")))
    steps = np.full(res.num_tracks, LABEL_STEPS.index("vote"), np.int8)  # every track: the vote's olive
    res = Result(**{**res.as_dict(), "label_step": steps})
    img = next(tracks_video_frames(res, frames, RenderConfig(color_by="step", max_tracks=50)))
    olive = np.array(D.STEP_COLORS["vote"][0])
    assert (np.abs(img.reshape(-1, 3).astype(int) - olive).max(1) <= 2).sum() > 20  # the tracks' dots


def test_points_and_the_tracks_video_coloured_by_their_rigid_object():
    from trackingworld.errors import InputError
    from trackingworld.viz.render import RenderConfig, tracks_video_frames

    res, frames = exact_result()
    idx = np.flatnonzero(res.visible[:, 2])
    _, _, plain = D.frame_points(res, 2, idx, len(idx), "object")  # no object_id: the label colours
    np.testing.assert_array_equal(plain, D.label_colors(res.is_dynamic[idx]))
    with pytest.raises(InputError, match="no object_id"):
        next(tracks_video_frames(res, frames, RenderConfig(color_by="object")))
    ids = np.full(res.num_tracks, -1, np.int32)
    ids[idx[:4]] = 0
    ids[idx[4:6]] = len(D.OBJECT_COLORS) + 1  # the colours cycle
    poses = np.tile(np.eye(4, dtype=np.float32), (len(D.OBJECT_COLORS) + 2, res.num_frames, 1, 1))
    obj = Result(**{**res.as_dict(), "object_id": ids, "object_poses": poses})
    _, _, col = D.frame_points(obj, 2, idx, len(idx), "object")
    np.testing.assert_array_equal(col[:4], np.tile(D.OBJECT_COLORS[0], (4, 1)))
    np.testing.assert_array_equal(col[4:6], np.tile(D.OBJECT_COLORS[1], (2, 1)))
    np.testing.assert_array_equal(col[6:], D.label_colors(res.is_dynamic[idx[6:]]))
    # no object colour is a label colour, so a track in an object never reads as merely static or dynamic
    assert not any((c == D.STATIC_COLOR).all() or (c == D.DYNAMIC_COLOR).all() for c in D.OBJECT_COLORS)
    every = Result(**{**res.as_dict(), "object_id": np.zeros(res.num_tracks, np.int32), "object_poses": poses[:1]})
    img = next(tracks_video_frames(every, frames, RenderConfig(color_by="object", max_tracks=50)))
    assert (np.abs(img.reshape(-1, 3).astype(int) - D.OBJECT_COLORS[0].astype(int)).max(1) <= 2).sum() > 20


def test_a_result_refuses_object_ids_past_its_objects():
    res, _ = exact_result()
    poses = np.tile(np.eye(4, dtype=np.float32), (2, res.num_frames, 1, 1))
    with pytest.raises(ValueError, match="object_id out of range"):
        Result(**{**res.as_dict(), "object_id": np.full(res.num_tracks, 2, np.int32), "object_poses": poses})
    with pytest.raises(ValueError, match="come together"):
        Result(**{**res.as_dict(), "object_id": np.zeros(res.num_tracks, np.int32)})
