"""Each export format read back through the library that reads it, against the exact result it came from."""

import json
import shutil

import numpy as np
import pytest

from exact_result import write_exact_result
from trackingworld.cli.main import main
from trackingworld.geometry import invert_pose, project, transform
from trackingworld.io.export import export


@pytest.fixture(scope="module")
def exact(tmp_path_factory):
    d = tmp_path_factory.mktemp("exact")
    res, frames = write_exact_result(d)
    return d, res, frames


def test_tum_reads_back_with_evo(exact):
    from evo.tools import file_interface

    d, res, _ = exact
    path = export(d, "tum", verbose=False)
    traj = file_interface.read_tum_trajectory_file(str(path))
    assert traj.num_poses == res.num_frames
    np.testing.assert_allclose(np.stack(traj.poses_se3), res.poses_c2w, atol=1e-6)


def test_colmap_reads_back_with_pycolmap(exact):
    pycolmap = pytest.importorskip("pycolmap")
    d, res, _ = exact
    path = export(d, "colmap", verbose=False)
    rec = pycolmap.Reconstruction(str(path))
    n_static = int((~res.is_dynamic).sum())
    assert rec.num_images() == res.num_frames and rec.num_points3D() == n_static
    cam = next(iter(rec.cameras.values()))
    K = res.intrinsics
    np.testing.assert_allclose(cam.params, [K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5], rtol=1e-5)
    for img in rec.images.values():
        t = img.image_id - 1
        w2c = np.eye(4)
        w2c[:3] = img.cam_from_world().matrix()
        np.testing.assert_allclose(w2c, invert_pose(res.poses_c2w[t].astype(np.float64)), atol=1e-6)
        assert img.name == f"frame_{t:05d}.jpg"
        assert img.num_points3D == int((res.visible[:, t] & ~res.is_dynamic).sum())
    # the result is exact: COLMAP's own reprojection error is (nearly) zero; colours and images came along
    assert rec.compute_mean_reprojection_error() < 0.01
    xyz = np.stack([p.xyz for p in rec.points3D.values()])
    assert np.abs(np.sort(xyz[:, 0]) - np.sort(res.tracks_3d[~res.is_dynamic, 0, 0])).max() < 1e-4
    assert len(list((path / "images").glob("*.jpg"))) == res.num_frames


def test_nerfstudio_poses_reproject_the_tracks(exact):
    d, res, _ = exact
    path = export(d, "nerfstudio", verbose=False)
    meta = json.loads((path / "transforms.json").read_text())
    assert meta["w"] == res.depth.shape[2] and len(meta["frames"]) == res.num_frames
    K = np.array([[meta["fl_x"], 0, meta["cx"]], [0, meta["fl_y"], meta["cy"]], [0, 0, 1]])
    n = np.flatnonzero(res.visible[:, 3])[:50]
    for t, fr in enumerate(meta["frames"]):
        c2w_gl = np.array(fr["transform_matrix"])
        cam_gl = transform(invert_pose(c2w_gl), res.tracks_3d[n, t].astype(np.float64))
        uv, _ = project(cam_gl * [1, -1, -1], K)  # OpenGL camera -> OpenCV camera
        ok = res.visible[n, t]
        np.testing.assert_allclose(uv[ok], res.tracks_2d[n, t][ok], atol=1e-3)
        assert (path / fr["file_path"]).exists()
        import imageio.v3 as iio

        depth = iio.imread(path / fr["depth_file_path"]) * meta["depth_unit_scale_factor"]
        np.testing.assert_allclose(depth, res.depth[t], atol=1e-3)
    assert (path / meta["ply_file_path"]).exists()


def test_ply_reads_back_with_trimesh(exact):
    trimesh = pytest.importorskip("trimesh")
    d, res, frames = exact
    path = export(d, "ply", verbose=False)
    for t in (0, 5):
        pc = trimesh.load(path / f"frame_{t:05d}.ply")
        vis = np.flatnonzero(res.visible[:, t])
        assert len(pc.vertices) == len(vis)
        # same set of points (the export orders them randomly)
        a = np.lexsort(np.asarray(pc.vertices).T)
        b = np.lexsort(res.tracks_3d[vis, t].T)
        np.testing.assert_allclose(np.asarray(pc.vertices)[a], res.tracks_3d[vis, t][b], atol=1e-5)
        dyn = pc.metadata["_ply_raw"]["vertex"]["data"]["dynamic"]
        assert int(dyn.sum()) == int(res.is_dynamic[vis].sum())
        assert np.asarray(pc.colors).shape == (len(vis), 4)
    static = trimesh.load(path / "static.ply")
    assert len(static.vertices) == int((~res.is_dynamic).sum())


def test_tapvid3d_layout_and_geometry(exact):
    d, res, _ = exact
    path = export(d, "tapvid3d", verbose=False)
    with np.load(path) as z:
        xyz, vis, q, f = z["tracks_XYZ"], z["visibility"], z["queries_xyt"], z["fx_fy_cx_cy"]
    T, N = res.num_frames, res.num_tracks
    assert xyz.shape == (T, N, 3) and vis.shape == (T, N) and q.shape == (N, 3) and f.shape == (4,)
    K = np.array([[f[0], 0, f[2]], [0, f[1], f[3]], [0, 0, 1]])
    uv, z = project(xyz.astype(np.float64), K)
    np.testing.assert_allclose(uv[vis], res.tracks_2d.transpose(1, 0, 2)[vis], atol=1e-3)
    assert (z[vis] > 0).all()
    np.testing.assert_array_equal(q[:, 2], res.query_frame)
    back = transform(res.poses_c2w[:, None].astype(np.float64), xyz.astype(np.float64))  # camera -> world
    np.testing.assert_allclose(back.transpose(1, 0, 2), res.tracks_3d, atol=1e-4)


def test_rrd_reads_back_with_rerun(exact):
    pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    d, res, _ = exact
    path = export(d, "rrd", verbose=False)
    chunks = RrdReader(path).stream().to_chunks()
    entities = {c.entity_path for c in chunks}
    assert {"/world/static_map", "/world/points", "/world/camera", "/world/camera/image",
            "/world/dynamic_trails", "/world/camera_path"} <= entities
    rows = sum(c.num_rows for c in chunks if c.entity_path == "/world/points")
    assert rows == res.num_frames  # one Points3D per frame on the frame timeline
    # the static map holds every static point at its position
    batch = next(c for c in chunks if c.entity_path == "/world/static_map").to_record_batch()
    col = next(n for n in batch.schema.names if n.endswith("positions"))
    pts = np.asarray(batch.column(col).to_pylist()[0], np.float32)
    assert len(pts) == int((~res.is_dynamic).sum())


def test_failed_export_leaves_nothing(exact, monkeypatch):
    import trackingworld.io.export.ply as ply

    d, _, _ = exact

    def boom(*a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(ply, "write_ply", boom)
    out = d / "export" / "ply_fail"
    with pytest.raises(RuntimeError):
        export(d, "ply", out=out, verbose=False)
    assert not out.exists()
    assert not [p for p in (d / "export").iterdir() if p.name.startswith(".")]


def test_cli_export_and_errors(exact, tmp_path, capsys):
    d, _, _ = exact
    assert main(["export", str(d), "--format", "tum", "--out", str(tmp_path / "t.txt"), "--quiet"]) == 0
    assert (tmp_path / "t.txt").read_text().count("\n") == 8
    assert main(["export", str(tmp_path / "missing"), "--format", "ply"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing" in err[0] and "no such result" in err[0]
    # an output under a file, and a render folder that is a file: refused before any work, nothing written
    (tmp_path / "afile").write_text("x")
    assert main(["export", str(d), "--format", "ply", "--out", str(tmp_path / "afile" / "p.ply"), "--quiet"]) == 2
    assert "afile is a file, not a folder" in capsys.readouterr().err
    shutil.copy(d / "result.npz", tmp_path / "result.npz")
    (tmp_path / "render").write_text("x")
    assert main(["render", str(tmp_path), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "render: cannot be the render folder" in err and len(err.splitlines()) == 1


def test_objects_read_back_with_evo_in_the_frames_each_is_solved_in(tmp_path):
    from evo.tools import file_interface
    from scipy.spatial.transform import Rotation

    from trackingworld.errors import InputError
    from trackingworld.io.result import Result, save_result

    d = tmp_path / "r"
    res, _ = write_exact_result(d)
    with pytest.raises(InputError, match="no object_id"):
        export(d, "objects", verbose=False)
    T = res.num_frames
    poses = np.full((2, T, 4, 4), np.nan, np.float32)
    for g, frames in enumerate((np.arange(T), np.arange(2, T - 1))):
        rot = Rotation.from_rotvec(np.outer(frames, [0.0, 0.05 * (g + 1), 0.01])).as_matrix()
        poses[g, frames] = np.eye(4)
        poses[g, frames, :3, :3] = rot
        poses[g, frames, :3, 3] = np.outer(frames, [0.1, 0.0, -0.05 * g]) + g
    ids = np.full(res.num_tracks, -1, np.int32)
    ids[:5], ids[5:8] = 0, 1
    save_result(d, Result(**{**res.as_dict(), "object_id": ids, "object_poses": poses}))
    out = export(d, "objects", verbose=False)
    listing = json.loads((out / "objects.json").read_text())["objects"]
    assert [o["tracks"] for o in listing] == [5, 3] and listing[1]["frames"] == [2, T - 2]
    for g, o in enumerate(listing):
        traj = file_interface.read_tum_trajectory_file(str(out / o["file"]))
        solved = np.flatnonzero(np.isfinite(poses[g, :, 0, 0]))
        np.testing.assert_array_equal(traj.timestamps, solved)
        np.testing.assert_allclose(np.stack(traj.poses_se3), poses[g, solved], atol=1e-6)
