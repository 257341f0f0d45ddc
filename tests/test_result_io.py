import numpy as np
import pytest

from trackingworld import Result, load_result, save_result
from trackingworld.errors import InputError
from trackingworld.io.atomic import atomic_path
from trackingworld.io.priors import load_depth, load_masks, parse_intrinsics


def make_result(N=5, T=4, H=6, W=8, rng=None):
    rng = rng or np.random.default_rng(0)
    return Result(
        tracks_2d=rng.uniform(0, 5, (N, T, 2)), visible=rng.random((N, T)) > 0.3,
        tracks_3d=rng.normal(size=(N, T, 3)), query_frame=rng.integers(0, T, N),
        is_dynamic=rng.random(N) > 0.5, colors=rng.integers(0, 255, (N, 3)),
        poses_c2w=np.tile(np.eye(4), (T, 1, 1)), intrinsics=np.eye(3), depth=rng.uniform(1, 2, (T, H, W)),
    )


def test_round_trip(tmp_path):
    r = make_result()
    save_result(tmp_path, r)
    back = load_result(tmp_path)
    for k, v in r.as_dict().items():
        got = getattr(back, k)
        assert got.dtype == Result.DTYPES[k], k
        np.testing.assert_array_equal(got, v)
    optional = {"label_step", "object_id", "object_poses"}  # none given
    assert set(np.load(tmp_path / "result.npz").files) == set(Result.DTYPES) - optional
    assert back.label_step is None and back.object_id is None and back.object_poses is None
    lines = (tmp_path / "poses_tum.txt").read_text().splitlines()
    assert len(lines) == 4 and lines[0].split() == ["0", *(["0.000000000"] * 6), "1.000000000"]


def test_the_rigid_objects_round_trip_with_their_unsolved_frames(tmp_path):
    r = make_result()
    T = r.num_frames
    for G in (0, 2):  # no object (the rigid step off, or nothing rigid), and two
        poses = np.tile(np.eye(4, dtype=np.float32), (G, T, 1, 1))
        if G:
            poses[1, :2] = np.nan  # the second object's motion is not solved in frames 0-1
        ids = np.full(r.num_tracks, -1, np.int32)
        ids[:G] = np.arange(G)
        save_result(tmp_path, Result(**{**r.as_dict(), "object_id": ids, "object_poses": poses}))
        back = load_result(tmp_path)
        np.testing.assert_array_equal(back.object_id, ids)
        assert back.object_poses.shape == (G, T, 4, 4) and back.object_poses.dtype == np.float32
        np.testing.assert_array_equal(back.object_poses, poses)  # NaN where it was


def test_tum_round_trip_with_evo(tmp_path):
    from evo.tools import file_interface
    from scipy.spatial.transform import Rotation

    r = make_result()
    r.poses_c2w[:, :3, :3] = Rotation.random(4, random_state=1).as_matrix()
    r.poses_c2w[:, :3, 3] = np.arange(12).reshape(4, 3)
    save_result(tmp_path, r)
    traj = file_interface.read_tum_trajectory_file(str(tmp_path / "poses_tum.txt"))
    np.testing.assert_allclose(np.stack(traj.poses_se3), r.poses_c2w, atol=1e-6)


def test_rejects_nan():
    r = make_result()
    r.tracks_3d[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        r.validate()


def test_shape_mismatch_rejected():
    with pytest.raises(ValueError, match="shape"):
        Result(**{**make_result().as_dict(), "colors": np.zeros((2, 3))})


def test_atomic_write_leaves_nothing_on_error(tmp_path):
    target = tmp_path / "x.npz"
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"partial")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_load_result_errors(tmp_path):
    with pytest.raises(InputError, match="no such result"):
        load_result(tmp_path)
    np.savez(tmp_path / "result.npz", a=np.zeros(1))
    with pytest.raises(InputError, match="missing keys"):
        load_result(tmp_path)
    whole = (tmp_path / "result.npz").read_bytes()
    (tmp_path / "result.npz").write_bytes(whole[: len(whole) // 2])  # a copy cut short
    with pytest.raises(InputError, match="result.npz: cannot read the result file: damaged or cut short"):
        load_result(tmp_path)


def test_read_arrays_by_content_and_its_errors(tmp_path):
    from trackingworld.io.arrays import read_array, read_arrays

    a = np.arange(6.0).reshape(2, 3)
    np.save(tmp_path / "a.npy", a)
    np.savez(tmp_path / "z.npz", other=np.zeros(2), depth=a)
    (tmp_path / "zip_named.npy").write_bytes((tmp_path / "z.npz").read_bytes())  # the content decides, not the name
    np.testing.assert_array_equal(read_arrays(tmp_path / "a.npy", "depth")[""], a)
    assert sorted(read_arrays(tmp_path / "z.npz", "depth")) == ["depth", "other"]
    for f in ("a.npy", "z.npz", "zip_named.npy"):
        np.testing.assert_array_equal(read_array(tmp_path / f, "depth", "depth"), a)
    np.testing.assert_array_equal(read_array(tmp_path / "z.npz", "masks", "masks"), np.zeros(2))  # the first member
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object))
    (tmp_path / "short.npy").write_bytes((tmp_path / "a.npy").read_bytes()[:-8])
    np.savez(tmp_path / "none.npz")
    for f, why in (("missing.npy", "cannot open the depth file"), ("obj.npy", "holds Python objects"),
                   ("short.npy", "damaged or cut short"), ("none.npz", "holds no array")):
        with pytest.raises(InputError, match=why) as e:
            read_array(tmp_path / f, "depth", "depth")
        assert str(e.value).startswith(str(tmp_path / f)) and "\n" not in str(e.value)


def test_priors_loaders(tmp_path):
    import imageio.v3 as iio

    d = np.random.default_rng(0).uniform(0.5, 5, (3, 4, 5)).astype(np.float32)
    np.save(tmp_path / "d.npy", d)
    np.testing.assert_array_equal(load_depth(tmp_path / "d.npy", 3), d)
    (tmp_path / "png").mkdir()
    for i in range(3):
        iio.imwrite(tmp_path / "png" / f"{i:03d}.png", (d[i] * 1000).astype(np.uint16))
    np.testing.assert_allclose(load_depth(tmp_path / "png", 3), d, atol=1e-3)
    with pytest.raises(InputError, match="frames"):
        load_depth(tmp_path / "d.npy", 5)
    m = np.zeros((3, 4, 5), bool)
    m[1, 2, 3] = True
    np.save(tmp_path / "m.npy", m)
    np.testing.assert_array_equal(load_masks(tmp_path / "m.npy", 3), m)
    np.testing.assert_array_equal(parse_intrinsics("100,110,50,40"),
                                  [[100, 0, 50], [0, 110, 40], [0, 0, 1]])
    (tmp_path / "K.txt").write_text("1 0 2\n0 3 4\n0 0 1\n")
    assert parse_intrinsics(tmp_path / "K.txt")[1, 2] == 4
    (tmp_path / "bad.txt").write_text("1 2 3\n")
    with pytest.raises(InputError, match="bad.txt"):
        parse_intrinsics(tmp_path / "bad.txt")
    (tmp_path / "K0.txt").write_text("300 0 160\n0 300 120\n0 0 0\n")  # a singular matrix (was a LinAlgError)
    with pytest.raises(InputError, match="K0.txt: intrinsics must be upper triangular with last row 0 0 1"):
        parse_intrinsics(tmp_path / "K0.txt")


def test_large_arrays_deflated_in_parts_on_threads_read_back_the_same(tmp_path, monkeypatch):
    import zipfile

    from trackingworld.io import atomic
    from trackingworld.optim import parallel

    monkeypatch.setattr(atomic, "NPZ_PARALLEL_BYTES", 4096)  # every array but the small ones in parts ...
    monkeypatch.setattr(atomic, "NPZ_PART", 1000)  # ... of 1,000 bytes (not a multiple of any item size)
    monkeypatch.setattr(parallel, "worker_threads", lambda limit=8: 3)
    rng = np.random.default_rng(0)
    arrays = {"xyz": rng.standard_normal((500, 7, 3)).astype(np.float32), "vis": rng.random((900, 11)) < 0.5,
              "conf": rng.random((300, 9)).astype(np.float16), "fortran": np.asfortranarray(rng.random((60, 50))),
              "ids": np.arange(5000, dtype=np.int64), "small": np.arange(3.0), "scalar": np.float64(2.5)}
    atomic.write_npz(tmp_path / "a.npz", **arrays)
    with zipfile.ZipFile(tmp_path / "a.npz") as z:
        assert z.testzip() is None  # every member's CRC and deflate stream
    back = np.load(tmp_path / "a.npz")
    assert sorted(back.files) == sorted(arrays)
    for k, v in arrays.items():
        assert back[k].dtype == np.asarray(v).dtype and np.array_equal(back[k], v)
    monkeypatch.setattr(atomic, "NPZ_PARALLEL_BYTES", 1 << 62)  # numpy's own writer: the same arrays
    atomic.write_npz(tmp_path / "b.npz", **arrays)
    ref = np.load(tmp_path / "b.npz")
    assert all(np.array_equal(ref[k], back[k]) for k in arrays)


def test_label_step_round_trip_and_shape(tmp_path):
    r = Result(**{**make_result().as_dict(), "label_step": np.array([0, 4, 5, 0, 8])})
    save_result(tmp_path, r)
    back = load_result(tmp_path)
    assert back.label_step.dtype == np.int8
    np.testing.assert_array_equal(back.label_step, [0, 4, 5, 0, 8])
    with pytest.raises(ValueError, match="label_step has shape"):
        Result(**{**make_result().as_dict(), "label_step": np.zeros(3)})


def test_check_writable_refuses_files_and_unwritable_folders_and_creates_nothing(tmp_path, monkeypatch):
    import os

    from trackingworld.io.atomic import check_writable

    check_writable(tmp_path / "a" / "b")  # to be made under a writable folder: fine, and not made
    assert not (tmp_path / "a").exists()
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError, match=r"cannot be the output folder: .*f is a file, not a folder"):
        check_writable(tmp_path / "f" / "out")
    monkeypatch.setattr(os, "access", lambda path, mode: False)  # as a read-only mount answers
    with pytest.raises(InputError, match="render folder: .* is not writable"):
        check_writable(tmp_path / "r", "render folder")
