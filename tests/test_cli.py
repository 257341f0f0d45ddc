import json
import shutil

import imageio.v3 as iio
import numpy as np
import pytest

from trackingworld import load_result
from trackingworld.cli.main import main


def test_run_and_eval_end_to_end(tiny_scene, tmp_path, capsys):
    inp = tiny_scene / "input"
    out = tmp_path / "res"
    rc = main(["run", str(inp / "frames"), "--out", str(out), "--depth", str(inp / "depth.npy"),
               "--masks", str(inp / "masks"), "--intrinsics", str(inp / "intrinsics.txt"), "--quiet",
               "--method", "baseline"])
    assert rc == 0
    r = load_result(out)
    assert r.tracks_2d.shape[1] == 10 and r.depth.shape == (10, 96, 128)
    assert np.isfinite(r.tracks_3d).all()
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["method"] == "baseline" and cfg["inputs"]["depth"].endswith("depth.npy")
    assert main(["eval", str(out), "--gt", str(tiny_scene)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["camera"]["ate"] > 0 and "abs_rel_depth" in m["track_depth_prior"]
    # the baseline returns the raw prior as its video depth: identical numbers on the same pixels
    assert m["video_depth"]["abs_rel_depth"] == pytest.approx(m["video_depth_prior"]["abs_rel_depth"])
    assert "ATE" in capsys.readouterr().out
    # a ground truth without query tracks (a clip cut from a longer video): the other metrics still come out
    g = dict(np.load(tiny_scene / "gt.npz"))
    for k in ("tracks_xyz", "tracks_uv", "tracks_vis", "query_frame", "query_uv", "tracks_dynamic",
              "tracks_bg_mover"):
        g[k] = g[k][:0]
    empty = tmp_path / "gt_empty"
    shutil.copytree(tiny_scene, empty)
    np.savez(empty / "gt.npz", **g)
    assert main(["eval", str(out), "--gt", str(empty)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["tracks_2d"]["queries_matched"] is None and m["world_3d"]["all"]["n_points"] == 0
    assert m["camera"]["ate"] > 0 and "abs_rel_depth" in m["track_depth"]


def test_run_with_resize_outputs_input_resolution(tiny_scene, tmp_path):
    inp = tiny_scene / "input"
    out = tmp_path / "res"
    assert main(["run", str(inp / "frames"), "--out", str(out), "--depth", str(inp / "depth.npy"),
                 "--resize", "64", "--max-frames", "6", "--quiet"]) == 0
    r = load_result(out)
    assert r.depth.shape == (6, 96, 128)
    assert r.tracks_2d[..., 0].max() > 100  # pixel coordinates at the input resolution
    rep = json.loads((out / "optim.json").read_text())  # what the optimiser found, per stage
    assert rep["stage2"]["loss"] <= rep["stage2"]["loss_init"] and "loss" in rep["stage1"]
    assert rep["vote_core"] == "off"  # no --masks: the weight-free motion masks, whose cores the vote may take back


@pytest.mark.parametrize("args,needle", [
    (["run", "nonexistent.mp4", "--out", "{out}"], "nonexistent.mp4: no such file"),
    (["run", "{frames}", "--out", "{out}", "--intrinsics", "1,2,3"], "intrinsics must hold"),
    (["run", "{frames}", "--out", "{out}", "--depth", "{bad}"], "depth must be"),
    (["eval", "{out}", "--gt", "{frames}"], "no such result"),
    # NumPy files that cannot be read: numpy's own errors are a traceback (a cut-short .npz, an empty .npy) or
    # misleading (a text file is "pickled data")
    (["run", "{frames}", "--out", "{out}", "--tracks", "{cut}", "--quiet"], "cut.npz: cannot read the tracks"),
    (["run", "{frames}", "--out", "{out}", "--depth", "{empty}", "--quiet"], "empty.npy: the depth file is empty"),
    (["run", "{frames}", "--out", "{out}", "--masks", "{text}", "--quiet"], "text.npy: the masks file is not a NumPy"),
    # an image that is not one: imageio's last plugin (PyAV) reads no frame from it, "need at least one array"
    (["run", "{frames}", "--out", "{out}", "--masks", "{junk}", "--quiet"], "00003.png: cannot read image: not an"),
    # an output that cannot be written, refused before any work
    (["run", "{frames}", "--out", "{bad}/o", "--quiet"], "bad.txt is a file, not a folder"),
    (["track2d", "{frames}", "--out", "{frames}", "--quiet"], "is a folder; --out names the tracks file"),
    # a processing resolution too small for the flow, refused before the tracking
    (["run", "{thin}", "--out", "{out}", "--resize", "32", "--quiet"], "processing at 32x3 px is too small"),
])
def test_bad_input_one_line_error(tiny_scene, tmp_path, capsys, args, needle):
    bad = tmp_path / "bad.txt"
    bad.write_text("x")
    np.savez(tmp_path / "whole.npz", tracks=np.zeros((50, 6, 2)), visible=np.ones((50, 6), bool))
    (tmp_path / "cut.npz").write_bytes((tmp_path / "whole.npz").read_bytes()[:200])
    (tmp_path / "empty.npy").write_bytes(b"")
    (tmp_path / "text.npy").write_text("0 1 0\n")
    shutil.copytree(tiny_scene / "input" / "masks", tmp_path / "junk")
    (tmp_path / "junk" / "00003.png").write_text("not a PNG")
    (tmp_path / "thin").mkdir()  # frames of 320x32 px: 32x3 at --resize 32
    for i in range(3):
        iio.imwrite(tmp_path / "thin" / f"{i:05d}.png", np.zeros((32, 320, 3), np.uint8))
    fill = {"out": str(tmp_path / "o"), "frames": str(tiny_scene / "input" / "frames"), "bad": str(bad),
            **{k: str(tmp_path / f) for k, f in (("cut", "cut.npz"), ("empty", "empty.npy"), ("text", "text.npy"),
                                         ("junk", "junk"), ("thin", "thin"))}}
    rc = main([a.format(**fill) for a in args])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and needle in err and len(err.splitlines()) == 1
    assert not (tmp_path / "o" / "result.npz").exists()


@pytest.mark.parametrize("case,needle", [
    # a resize would smear a rotated or transposed array over the frames
    ("depth_T", "depth.npy: depth of 96x128 px for frames of 128x96: height and width swapped"),
    ("masks_T", "masks.npy: masks of 96x128 px for frames of 128x96: height and width swapped"),
    # millimetres in an integer .npy are not guessed
    ("depth_mm", "depth.npy: depth holds uint16 numbers; give float metres"),
    # intrinsics of another resolution bend every ray
    ("intrinsics", "the principal point (640, 48) px lies outside the 128x96 frames"),
    # a track2d file records its frames' size; another tracker's points must lie on the frames
    ("tracks_size", "tracks.npz: the tracks were made on 256x192 frames, this video's are 128x96"),
    ("tracks_extent", "tracks.npz: 100% of the visible track points lie outside the 128x96 frames"),
])
def test_inputs_of_another_video_refused(tiny_scene, tmp_path, capsys, case, needle):
    """Depth, masks, intrinsics and tracks that belong to frames of another size or orientation: one line naming the
    file and the problem, before any work, no result (they ran to the end before, on smeared or shifted inputs)."""
    inp = tiny_scene / "input"
    depth = np.load(inp / "depth.npy")
    masks = np.stack([iio.imread(f) > 0 for f in sorted((inp / "masks").glob("*.png"))])
    given = {"--depth": str(inp / "depth.npy"), "--masks": str(inp / "masks"),
             "--intrinsics": str(inp / "intrinsics.txt")}
    if case == "depth_T":
        np.save(tmp_path / "depth.npy", depth.transpose(0, 2, 1))
        given["--depth"] = str(tmp_path / "depth.npy")
    elif case == "masks_T":
        np.save(tmp_path / "masks.npy", masks.transpose(0, 2, 1))
        given["--masks"] = str(tmp_path / "masks.npy")
    elif case == "depth_mm":
        np.save(tmp_path / "depth.npy", (depth * 1000).astype(np.uint16))
        given["--depth"] = str(tmp_path / "depth.npy")
    elif case == "intrinsics":
        given["--intrinsics"] = "100,100,640,48"
    else:
        T = depth.shape[0]
        uv = np.random.default_rng(0).uniform(0, 90, (40, T, 2))
        if case == "tracks_size":
            np.savez(tmp_path / "tracks.npz", tracks=uv, visible=np.ones((40, T), bool), size=np.array([256, 192]))
        else:  # CoTracker's layout [T,N,2], its points on frames 4x as large
            np.savez(tmp_path / "tracks.npz", tracks=(uv * 4 + 200).transpose(1, 0, 2), visibility=np.ones((T, 40)))
        given["--tracks"] = str(tmp_path / "tracks.npz")
    rc = main(["run", str(inp / "frames"), "--out", str(tmp_path / "o"), "--quiet",
               *[x for kv in given.items() for x in kv]])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and needle in err and len(err.splitlines()) == 1
    assert not (tmp_path / "o" / "result.npz").exists()


def test_prior_of_another_aspect_ratio_warned_and_stretched(tiny_scene, tmp_path):
    """A depth map of another aspect ratio is stretched to the frames (right for a model run on squeezed frames),
    with a warning naming the file; one of the frames' aspect ratio at another size is resized without a word."""
    import warnings

    from trackingworld.config import InputConfig
    from trackingworld.pipeline.inputs import load_inputs

    inp = tiny_scene / "input"
    depth = np.load(inp / "depth.npy")
    np.save(tmp_path / "crop.npy", depth[:, 10:-10])  # 128x76: cropped
    np.save(tmp_path / "half.npy", depth[:, ::2, ::2])  # 64x48: the frames' aspect ratio
    with pytest.warns(RuntimeWarning, match="crop.npy: depth of 128x76 px, another aspect ratio than the 128x96"):
        got = load_inputs(InputConfig(input=str(inp / "frames"), depth=str(tmp_path / "crop.npy")), verbose=False)
    assert got.depth.shape == depth.shape
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = load_inputs(InputConfig(input=str(inp / "frames"), depth=str(tmp_path / "half.npy")), verbose=False)
    assert got.depth.shape == depth.shape


@pytest.mark.parametrize("args,needle", [
    (["run", "{frames}", "--out", "{out}", "--resize", "-5"], "argument --resize: must be >= 32, got '-5'"),
    (["run", "{frames}", "--out", "{out}", "--max-frames", "0"], "argument --max-frames: must be >= 1, got '0'"),
    (["run", "{frames}", "--out", "{out}", "--lambda-ba", "-1"], "argument --lambda-ba: must be >= 0, got '-1'"),
    (["run", "{frames}", "--out", "{out}", "--epsilon", "nan"], "argument --epsilon: must be > 0, got 'nan'"),
    (["track2d", "{frames}", "--out", "{out}.npz", "--grid-stride", "x"], "--grid-stride: expected an integer"),
    (["synth", "{out}", "--frames", "1"], "argument --frames: must be >= 2, got '1'"),
    # a list that starts with a minus sign is the option's value, not an option (argparse: "expected one argument")
    (["run", "{frames}", "--out", "{out}", "--intrinsics", "-100,100,160,120"],
     "-100,100,160,120: intrinsics need positive finite focal lengths"),
    (["track2d", "{frames}", "--out", "{out}.npz", "--flow-patch", "-8,4"], "--flow-patch: the patch stride must be"),
])
def test_numbers_out_of_range_refused_by_the_parser(tiny_scene, tmp_path, capsys, args, needle):
    rc = main([a.format(out=str(tmp_path / "o"), frames=str(tiny_scene / "input" / "frames")) for a in args])
    assert rc == 2 and needle in capsys.readouterr().err  # argparse's usage, then its one error line
    assert not (tmp_path / "o").exists() and not (tmp_path / "o.npz").exists()


def test_a_file_system_error_is_one_line(tiny_scene, tmp_path, capsys, monkeypatch):
    import errno

    import trackingworld.pipeline.run as pr

    def full_disk(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "o" / "result.npz"))

    monkeypatch.setattr(pr, "run", full_disk)
    rc = main(["run", str(tiny_scene / "input" / "frames"), "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and err.endswith("result.npz: No space left on device") and len(err.splitlines()) == 1


def test_offset_stat_takes_any_percentile(capsys):
    from trackingworld.cli.main import _optim_config, build_parser

    a = build_parser().parse_args(["run", "x", "--out", "o", "--offset-stat", "p50", "--epsilon", "0.05"])
    cfg = _optim_config(a)
    assert (cfg.offset_stat, cfg.epsilon) == ("p50", 0.05)
    with pytest.raises(SystemExit):
        build_parser().parse_args(["run", "x", "--out", "o", "--offset-stat", "p200"])
    assert "not max or a percentile" in capsys.readouterr().err


def test_stage3_options_reach_the_config():
    from trackingworld.cli.main import _optim_config, build_parser
    from trackingworld.config import OptimConfig

    cfg = _optim_config(build_parser().parse_args(["run", "x", "--out", "o", "--carry-k", "4", "--carry-reach", "1.5",
                                                   "--ts-order", "1", "--stage3-linear", "amg", "--slip-run", "0.5",
                                                   "--slip-px", "3", "--dc-edge-sigma", "0",
                                                   "--vote-colour-sigma", "0", "--vote-k", "5",
                                                   "--dc-target-smooth", "0.02", "--dc-field-smooth", "0.03",
                                                   "--dc-target-order", "2",
                                                   "--dynamic-cell", "2", "--depth-mover-rounds", "4",
                                                   "--depth-mover-suspect", "0.7", "--depth-mover-mad", "4",
                                                   "--photo-static", "16",
                                                   "--photo-static-frac", "0.6", "--photo-static-patch", "5",
                                                   "--vote-once-gap", "inf", "--no-rigid-movers",
                                                   "--rigid-second-pass", "0", "--mask-core-px", "0",
                                                   "--rigid-key-frames", "0", "--depth-mover-bin", "0.2",
                                                   "--depth-mover-bin-factor", "3"]))
    assert (cfg.carry_k, cfg.carry_reach, cfg.ts_order, cfg.stage3_linear) == (4, 1.5, 1, "amg")
    assert (cfg.slip_run, cfg.slip_px, cfg.dc_edge_sigma_px) == (0.5, 3.0, 0.0)
    assert (cfg.vote_colour_sigma, cfg.vote_k, cfg.dc_target_smooth, cfg.dc_field_smooth) == (0.0, 5, 0.02, 0.03)
    assert cfg.dc_target_order == 2
    assert (cfg.dynamic_cell, cfg.depth_mover_rounds, cfg.depth_mover_suspect, cfg.depth_mover_mad) == (2, 4, 0.7, 4.0)
    assert (cfg.photo_static_grey, cfg.photo_static_frac, cfg.vote_once_gap_px) == (16.0, 0.6, np.inf)
    assert cfg.photo_static_patch == 5.0 and not cfg.rigid_movers and cfg.rigid_second_pass == 0
    default = _optim_config(build_parser().parse_args(["run", "x", "--out", "o"]))
    assert default.rigid_movers and default.rigid_second_pass == 30
    assert cfg.rigid_key_frames == 0 and default.rigid_key_frames == 48
    assert (cfg.depth_mover_bin, cfg.depth_mover_bin_factor) == (0.2, 3.0)
    assert cfg.mask_core_px == 0 and default.mask_core_px == OptimConfig().mask_core_px == 10
    d = OptimConfig()
    got = (default.carry_k, default.carry_reach, default.ts_order, default.stage3_linear)
    assert got == (d.carry_k, d.carry_reach, d.ts_order, d.stage3_linear) == (d.carry_k, d.carry_reach, 2, "cg")
    for bad in (["--ts-order", "3"], ["--dc-target-order", "3"]):
        with pytest.raises(SystemExit):
            build_parser().parse_args(["run", "x", "--out", "o", *bad])
    # the depth-discrepancy test's range: estimated from the prior (None) unless a whole number of px is given
    assert default.depth_mover_range_px is d.depth_mover_range_px is None
    for text, want in (("auto", None), ("0", 0), ("3", 3)):
        args = build_parser().parse_args(["run", "x", "--out", "o", "--depth-mover-range", text])
        assert _optim_config(args).depth_mover_range_px == want
    for bad in ("-1", "1.5", "wide"):
        with pytest.raises(SystemExit):
            build_parser().parse_args(["run", "x", "--out", "o", "--depth-mover-range", bad])


def test_unknown_optimiser_choice_is_refused_before_any_work(tmp_path):
    from types import SimpleNamespace

    import numpy as np

    from trackingworld.config import TS_ORDERS, OptimConfig, RunConfig
    from trackingworld.errors import InputError
    from trackingworld.optim import stage3
    from trackingworld.pipeline.run import run
    from trackingworld.pipeline.world import run_trackingworld

    assert tuple(sorted(stage3.TS_COEFS)) == TS_ORDERS  # the CLI's choices are the solver's orders
    inp = SimpleNamespace(depth=np.ones((2, 4, 4), np.float32))  # nothing else is read before the check
    with pytest.raises(InputError, match="ts_order: 3 is not 1 or 2"):
        run_trackingworld(inp, None, RunConfig(optim=OptimConfig(ts_order=3)))
    with pytest.raises(InputError, match="refine_focal: 'yes' is not auto or on or off"):
        run_trackingworld(inp, None, RunConfig(optim=OptimConfig(refine_focal="yes")))
    with pytest.raises(InputError, match="stage3_linear: 'lu' is not cg or amg"):
        run_trackingworld(inp, None, RunConfig(optim=OptimConfig(stage3_linear="lu")))
    for bad in (dict(slip_run=1.5), dict(slip_run=-0.1), dict(slip_px=0.0), dict(slip_window=0)):
        with pytest.raises(InputError, match="the run's fraction is from 0 to 1"):
            run_trackingworld(inp, None, RunConfig(optim=OptimConfig(**bad)))
    with pytest.raises(InputError, match="dc_edge_sigma_px -1.0: a Gaussian's width"):
        run_trackingworld(inp, None, RunConfig(optim=OptimConfig(dc_edge_sigma_px=-1.0)))
    for bad in (dict(dc_target_smooth=-0.1), dict(dc_field_smooth=-1.0), dict(dc_field_temporal=-1.0),
                dict(dynamic_cell=-2)):
        with pytest.raises(InputError, match="the fields' weights and the cell are 0 or more"):
            run_trackingworld(inp, None, RunConfig(optim=OptimConfig(**bad)))
    with pytest.raises(InputError, match="dynamic_cell -2: the fields' weights"):  # before any work
        run(RunConfig(optim=OptimConfig(dynamic_cell=-2)), tmp_path / "never")
    assert not (tmp_path / "never").exists()
    for bad in (dict(vote_colour_sigma=-1.0), dict(vote_k=0), dict(vote_once_gap_px=-1.0),
                dict(vote_once_gap_px=float("nan"))):
        with pytest.raises(InputError, match="the colour weight's width is 0 \\(off\\) or more"):
            run_trackingworld(inp, None, RunConfig(optim=OptimConfig(**bad)))
    for bad in (dict(depth_mover_rounds=0), dict(depth_mover_suspect=0.0), dict(depth_mover_suspect=1.5),
                dict(depth_mover_range_px=-1), dict(depth_mover_mad=-1.0), dict(depth_mover_mad=float("nan"))):
        with pytest.raises(InputError, match="the rounds are 1 or more"):
            run_trackingworld(inp, None, RunConfig(optim=OptimConfig(**bad)))
    for bad in (dict(depth_mover_bin=-0.1), dict(depth_mover_bin=float("nan")), dict(depth_mover_bin_factor=-1.0)):
        with pytest.raises(InputError, match="the depth bins' width is 0 \\(off\\) or more"):
            run_trackingworld(inp, None, RunConfig(optim=OptimConfig(**bad)))
    for bad in (dict(photo_static_grey=-1.0), dict(photo_static_frac=1.2), dict(photo_static_frames=0),
                dict(photo_static_near_px=-1.0), dict(photo_static_range=1.0), dict(photo_static_patch=-1.0),
                dict(photo_static_patch=float("nan"))):
        with pytest.raises(InputError, match="tolerance is 0 \\(off\\) or more"):
            run_trackingworld(inp, None, RunConfig(optim=OptimConfig(**bad)))


def test_video_input(tiny_scene, tmp_path):
    import imageio.v3 as iio

    frames = np.stack([iio.imread(p) for p in sorted((tiny_scene / "input" / "frames").glob("*.png"))])
    video = tmp_path / "v.mp4"
    iio.imwrite(video, frames, plugin="pyav", codec="libx264", fps=10)
    out = tmp_path / "res"
    assert main(["run", str(video), "--out", str(out), "--quiet", "--frame-stride", "2", "--method", "baseline"]) == 0
    assert load_result(out).num_frames == 5


def test_flow_tracker_settings_out_of_range_are_refused_before_any_work(tmp_path, capsys):
    from trackingworld.cli.main import main
    from trackingworld.config import RunConfig, Track2DConfig
    from trackingworld.errors import InputError
    from trackingworld.pipeline.run import run

    for bad in (dict(flow_refind_patch_diff=-1.0), dict(flow_refind_patch_diff=float("nan")),
                dict(flow_drag_px=-0.5), dict(flow_median=-3), dict(flow_skip_stride=-4)):
        field = next(iter(bad))
        with pytest.raises(InputError, match=f"{field} .*: 0 \\(off\\) or a positive number"):
            run(RunConfig(track2d=Track2DConfig(**bad)), tmp_path / "never")
    assert not (tmp_path / "never").exists()
    # the CLI says so in one line, before it looks for the (missing) video
    code = main(["track2d", str(tmp_path / "missing.mp4"), "--out", str(tmp_path / "t.npz"),
                 "--flow-refind-patch-diff", "-1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "flow_refind_patch_diff -1.0" in err[0]
    assert not (tmp_path / "t.npz").exists()


def test_track2d_writes_the_trackers_pixels_to_the_bit(tiny_scene, tmp_path):
    """At the video's own size `track2d` writes the tracker's positions unchanged: the conversion to input pixels,
    ``(x + 0.5) * 1 - 0.5`` in float32, used to move 1 in 5 of them by a unit in the last place (`hard` 20), and a
    run on such a file then differs from a run on the tracks themselves. With ``--resize`` the positions are scaled
    to the input's pixels."""
    from trackingworld.config import InputConfig, Track2DConfig
    from trackingworld.pipeline.inputs import load_inputs
    from trackingworld.pipeline.tracks import track_video

    frames = tiny_scene / "input" / "frames"
    assert main(["track2d", str(frames), "--out", str(tmp_path / "t.npz"), "--quiet"]) == 0
    inp = load_inputs(InputConfig(input=str(frames)), verbose=False)
    tr = track_video(inp.frames, Track2DConfig(), verbose=False)
    np.testing.assert_array_equal(np.load(tmp_path / "t.npz")["tracks"], tr.tracks)
    half = load_inputs(InputConfig(input=str(frames), resize=64), verbose=False)
    uv = np.array([[0.0, 0.0], [31.5, 10.25]], np.float32)
    np.testing.assert_allclose(half.to_input_pixels(uv), [[0.5, 0.5], [63.5, 21.0]])
