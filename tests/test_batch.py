"""``trackingworld run`` over several videos (pipeline.batch): a folder each, {name} in the prior paths, a failure
passed over and recorded, finished videos skipped on a re-run."""

import json
import shutil

import numpy as np
import pytest

from trackingworld import load_result
from trackingworld.cli.main import main
from trackingworld.config import InputConfig, RunConfig, Track2DConfig
from trackingworld.errors import InputError
from trackingworld.pipeline.batch import check_per_video, config_for, finished, video_names


@pytest.fixture
def videos(tiny_scene, tmp_path):
    """Two videos as image folders ``videos/a``, ``videos/b`` (``b`` the first 6 frames of ``a``), each with its
    depth file ``depth/<name>.npy`` and mask folder ``masks/<name>``."""
    inp = tiny_scene / "input"
    depth = np.load(inp / "depth.npy")
    for name, T in (("a", 10), ("b", 6)):
        (tmp_path / "videos" / name).mkdir(parents=True)
        (tmp_path / "masks" / name).mkdir(parents=True)
        for sub in ("frames", "masks"):
            dst = tmp_path / ("videos" if sub == "frames" else "masks") / name
            for f in sorted((inp / sub).iterdir())[:T]:
                shutil.copy(f, dst / f.name)
        (tmp_path / "depth").mkdir(exist_ok=True)
        np.save(tmp_path / "depth" / f"{name}.npy", depth[:T])
    return tmp_path


@pytest.fixture
def restore_threads():
    """The process's thread settings as they were after the test (``--threads`` caps them for the process)."""
    import cv2
    import torch

    from trackingworld.optim import parallel

    before = (torch.get_num_threads(), cv2.getNumThreads(), parallel._cap)
    yield
    torch.set_num_threads(before[0])
    cv2.setNumThreads(before[1])
    parallel._cap = before[2]


def _args(root, *inputs, extra=()):
    return ["run", *[str(root / "videos" / i) for i in inputs], "--out", str(root / "out"),
            "--depth", str(root / "depth" / "{name}.npy"), "--masks", str(root / "masks" / "{name}"),
            "--intrinsics", str(root / "K.txt"), "--method", "baseline", "--quiet", *extra]


def test_batch_runs_each_video_into_its_own_folder_and_resumes(videos, tiny_scene, capsys):
    shutil.copy(tiny_scene / "input" / "intrinsics.txt", videos / "K.txt")  # one camera: one file serves all
    assert main(_args(videos, "a", "b")) == 0
    ra, rb = load_result(videos / "out" / "a"), load_result(videos / "out" / "b")
    assert ra.tracks_2d.shape[1] == 10 and rb.tracks_2d.shape[1] == 6  # each read its own frames and depth
    cfg_b = json.loads((videos / "out" / "b" / "config.json").read_text())
    assert cfg_b["inputs"]["depth"].endswith("depth/b.npy") and cfg_b["inputs"]["masks"].endswith("masks/b")
    s = json.loads((videos / "out" / "batch.json").read_text())
    assert (s["inputs"], s["done"], s["skipped"], s["failed"]) == (2, 2, 0, 0)
    assert [v["status"] for v in s["videos"]] == ["done", "done"] and all(v["seconds"] > 0 for v in s["videos"])
    assert "2 done, 0 skipped, 0 failed of 2" in capsys.readouterr().out
    # a re-run with --skip-done leaves the finished folders alone; a third video is run
    shutil.copytree(videos / "videos" / "b", videos / "videos" / "c")
    np.save(videos / "depth" / "c.npy", np.load(videos / "depth" / "b.npy"))
    shutil.copytree(videos / "masks" / "b", videos / "masks" / "c")
    before = (videos / "out" / "a" / "result.npz").stat().st_mtime_ns
    assert main(_args(videos, "a", "b", "c", extra=["--skip-done"])) == 0
    assert (videos / "out" / "a" / "result.npz").stat().st_mtime_ns == before
    s = json.loads((videos / "out" / "batch.json").read_text())
    assert [v["status"] for v in s["videos"]] == ["skipped", "skipped", "done"]
    assert finished(videos / "out" / "c")


def test_a_failing_video_is_recorded_and_the_batch_goes_on(videos, tiny_scene, capsys):
    shutil.copy(tiny_scene / "input" / "intrinsics.txt", videos / "K.txt")
    (videos / "depth" / "a.npy").write_text("not an array")  # a's depth file is broken
    assert main(_args(videos, "a", "b")) == 1
    captured = capsys.readouterr()
    s = json.loads((videos / "out" / "batch.json").read_text())
    assert [v["status"] for v in s["videos"]] == ["failed", "done"]
    assert "a.npy" in s["videos"][0]["error"] and "traceback" not in s["videos"][0]  # an InputError: one line
    assert not (videos / "out" / "a" / "result.npz").exists() and finished(videos / "out" / "b")
    assert "1 done, 0 skipped, 1 failed of 2" in captured.out
    # one line naming the video and the file at fault
    assert any(line.startswith("trackingworld run: ") and "videos/a: error: " in line and "depth/a.npy" in line
               for line in captured.err.splitlines())


def test_one_file_for_several_videos_and_clashing_names_are_refused_before_any_work(videos, tmp_path, capsys):
    frames = str(videos / "videos" / "a")
    rc = main(["run", frames, str(videos / "videos" / "b"), "--out", str(tmp_path / "o"),
               "--depth", str(videos / "depth" / "a.npy"), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "--depth" in err and "{name}" in err and len(err.splitlines()) == 1
    (videos / "elsewhere").mkdir()
    shutil.copytree(frames, videos / "elsewhere" / "a")
    rc = main(["run", frames, str(videos / "elsewhere" / "a"), "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "'a'" in err and len(err.splitlines()) == 1
    rc = main(["run", frames, str(videos / "videos" / "b"), "--out", str(tmp_path / "o"), "--quiet",
               "--photo-moving", "1.5"])  # a bad setting: refused once for the batch, not once per video
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "photo_moving_share 1.5" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_names_and_per_video_settings(tmp_path):
    (tmp_path / "clip").mkdir()
    assert video_names([str(tmp_path / "clip") + "/", "x/dog.mp4", "y/dog.mov.mp4"]) == ["clip", "dog", "dog.mov"]
    with pytest.raises(InputError, match="x/dog.mp4 and y/dog.mp4"):
        video_names(["x/dog.mp4", "y/dog.mp4"])
    cfg = RunConfig(inputs=InputConfig(depth="d/{name}.npy", masks="motion", intrinsics="K/{name}.txt"),
                    track2d=Track2DConfig(tracker="file", tracks_file="t/{name}.npz"))
    check_per_video(cfg)  # every file holds {name}; the weight-free masks need nothing
    one = config_for(cfg, "v/dog.mp4", "dog")
    assert (one.inputs.input, one.inputs.depth, one.inputs.masks, one.inputs.intrinsics, one.track2d.tracks_file) \
        == ("v/dog.mp4", "d/dog.npy", "motion", "K/dog.txt", "t/dog.npz")
    with pytest.raises(InputError, match="--tracks t.npz"):
        check_per_video(RunConfig(track2d=Track2DConfig(tracker="file", tracks_file="t.npz")))
    check_per_video(RunConfig(inputs=InputConfig(depth="none", intrinsics="K.txt")))  # shared camera: allowed


def test_skip_done_with_one_video(tiny_scene, tmp_path, capsys):
    inp = tiny_scene / "input"
    out = tmp_path / "res"
    args = ["run", str(inp / "frames"), "--out", str(out), "--depth", str(inp / "depth.npy"), "--method",
            "baseline", "--max-frames", "4", "--quiet", "--skip-done"]
    assert main(args) == 0 and finished(out)
    before = (out / "result.npz").stat().st_mtime_ns
    assert main(args) == 0 and (out / "result.npz").stat().st_mtime_ns == before
    assert "already holds a finished run" in capsys.readouterr().out


def test_jobs_run_videos_at_once_in_processes_with_the_same_results(videos, tiny_scene, capsys, restore_threads):
    shutil.copy(tiny_scene / "input" / "intrinsics.txt", videos / "K.txt")
    assert main(_args(videos, "a", "b")) == 0  # one at a time, into out/
    shutil.move(videos / "out", videos / "one_at_a_time")
    shutil.copytree(videos / "videos" / "b", videos / "videos" / "c")
    np.save(videos / "depth" / "c.npy", np.zeros(3))  # c's depth is broken: recorded, the others go on
    shutil.copytree(videos / "masks" / "b", videos / "masks" / "c")
    assert main(_args(videos, "a", "b", "c", extra=["--jobs", "2", "--threads", "1"])) == 1
    err = capsys.readouterr().err
    assert "2 at once, 1 threads each" in err
    s = json.loads((videos / "out" / "batch.json").read_text())
    assert [v["input"].rsplit("/", 1)[-1] for v in s["videos"]] == ["a", "b", "c"]  # the inputs' order
    assert [v["status"] for v in s["videos"]] == ["done", "done", "failed"] and "c.npy" in s["videos"][2]["error"]
    for name in ("a", "b"):
        r1, r2 = load_result(videos / "one_at_a_time" / name), load_result(videos / "out" / name)
        np.testing.assert_allclose(r2.tracks_2d, r1.tracks_2d, atol=1e-3)
        np.testing.assert_allclose(r2.tracks_3d, r1.tracks_3d, atol=1e-3)
    for inputs in (("a", "b"), ("a",)):
        rc = main(_args(videos, *inputs, extra=["--jobs", "0"]))
        assert rc == 2 and "argument --jobs: must be >= 1, got '0'" in capsys.readouterr().err
    rc = main(["track2d", str(videos / "videos" / "a"), "--out", str(videos / "t.npz"), "--threads", "0"])
    assert rc == 2 and "argument --threads: must be >= 1, got '0'" in capsys.readouterr().err
    assert not (videos / "t.npz").exists()


def test_thread_cap_limits_torch_opencv_and_the_frame_loops(restore_threads):
    import cv2
    import torch

    from trackingworld.optim import parallel

    parallel.set_thread_cap(1)
    assert torch.get_num_threads() == 1 and cv2.getNumThreads() == 1 and parallel.worker_threads() == 1
