"""``trackingworld`` command: synth, run, track2d, eval, view, render, export."""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

from trackingworld.errors import InputError
from trackingworld.memory import reuse_freed_memory


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = text.lower().split("x")
        return int(w), int(h)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"size must look like 320x240, got {text!r}") from e


def _xyz(text: str) -> tuple[float, float, float]:
    try:
        x, y, z = (float(v) for v in text.split(","))
        return x, y, z
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"expected X,Y,Z, got {text!r}") from e


def _at_least(lo: float, kind: type = int, above: bool = False):
    """An argparse type: a number of ``kind`` at least ``lo`` (greater than it with ``above``), else argparse's
    error naming the option, before any work starts (a negative --resize used to reach OpenCV's flow)."""
    def parse(text: str):
        try:
            v = kind(text)
        except ValueError as e:
            raise argparse.ArgumentTypeError(f"expected {'an integer' if kind is int else 'a number'}, "
                                             f"got {text!r}") from e
        if not (v > lo if above else v >= lo) or v != v:  # v != v: NaN
            raise argparse.ArgumentTypeError(f"must be {'>' if above else '>='} {lo:g}, got {text!r}")
        return v
    parse.__name__ = kind.__name__  # argparse's "invalid <name> value" for errors raised elsewhere
    return parse


POSITIVE_INT = _at_least(1)
NON_NEGATIVE = _at_least(0.0, float)
POSITIVE = _at_least(0.0, float, above=True)
MIN_RESIZE = 32  # px, the smallest --resize (the long side); the short side is checked against
# pipeline.inputs.MIN_SIDE_PX (16) once the video's size is known


def _patch(text: str) -> tuple[int, int]:
    """``SIZE,STRIDE`` of the DIS patches: positive integers, the stride at most the size."""
    try:
        size, stride = (int(v) for v in text.split(","))
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"expected SIZE,STRIDE (e.g. 4,2), got {text!r}") from e
    if not 0 < stride <= size:
        raise argparse.ArgumentTypeError(f"the patch stride must be 1..SIZE, got {text!r}")
    return size, stride


def _offset_stat(text: str) -> str:
    """``max`` or a percentile ``pNN`` (p0-p100) of a track's offset norms."""
    from trackingworld.config import offset_percentile

    try:
        offset_percentile(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from e
    return text


def _range_px(text: str) -> int | None:
    """``auto`` (None) or a whole number of pixels, 0 or more."""
    if text == "auto":
        return None
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r} is not auto or a whole number of pixels (0 or more)")
    return value


def build_parser() -> argparse.ArgumentParser:
    from trackingworld.config import SFM_CONTACTS

    p = argparse.ArgumentParser(prog="trackingworld", description=__doc__.split("\n")[0] if __doc__ else None)
    p.add_argument("--version", action="store_true", help="print the version and exit")
    sub = p.add_subparsers(dest="cmd")

    s = sub.add_parser("synth", help="render a synthetic scene with exact ground truth")
    s.add_argument("out")
    s.add_argument("--preset", default="default", choices=["easy", "default", "hard"])
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--frames", type=_at_least(2), default=None)
    s.add_argument("--size", type=_size, default=None, help="WxH, e.g. 320x240")
    s.add_argument("--fov", type=POSITIVE, default=None, help="horizontal field of view, degrees (default 60)")
    s.add_argument("--grounded", action="store_true",
                   help="movers stand and slide on the floor instead of floating (as people and cars do)")

    r = sub.add_parser("run", help="world-centric dense 3D tracking of a video")
    r.add_argument("input", nargs="+", help="video file or folder of images; several: one result folder each, "
                   "DIR/<name>/ (a file's stem or a folder's name), a failure reported and the batch going on, "
                   "DIR/batch.json the account")
    r.add_argument("--out", required=True, help="output folder")
    r.add_argument("--skip-done", action="store_true",
                   help="leave out a video whose output folder already holds a finished run (resume a batch)")
    r.add_argument("--jobs", type=POSITIVE_INT, default=1, metavar="J",
                   help="with several inputs: run J videos at once, each in its own process with the CPUs shared out "
                        "(or --threads each); their progress lines are left out (default 1: one at a time)")
    _threads_arg(r)
    g = r.add_argument_group("priors (default: weight-free, from the video itself)")
    g.add_argument("--depth", help="FILE (.npy/.npz [T,H,W] metres, or folder of 16-bit PNG mm) | MODEL (e.g. "
                   "depth-anything-v2-small, depth-pro, zoedepth, unidepth, hf:ID, or a local model folder) | "
                   "sfm (default: structure from motion, arbitrary scale) | none (constant depth)")
    g.add_argument("--masks", help="DIR of PNGs (non-zero = dynamic) | FILE .npy bool [T,H,W] | MODEL (grounded-sam "
                   "or DETECTOR+SEGMENTER) | motion (default: motion the camera cannot explain) | none")
    g.add_argument("--mask-prompt", help="text prompt of a mask model, e.g. 'dog. person.'")
    g.add_argument("--intrinsics", help="FILE (3x3 or fx,fy,cx,cy) | inline fx,fy,cx,cy | auto (default: the depth "
                   "model's focal length when it has one, else self-calibrated from the video's static tracks, "
                   "else --fov)")
    g.add_argument("--fov", type=POSITIVE, default=60.0,
                   help="horizontal field of view (deg) assumed when nothing better is known (default 60)")
    g.add_argument("--sfm-contact", choices=SFM_CONTACTS, default=SFM_CONTACTS[0],
                   help="how the SfM depth fills a dynamic region: column (default: each column takes the ground "
                   "just below it) | region (one value each, the median of its border below; before stop 78)")
    g.add_argument("--no-self-calibration", action="store_true",
                   help="with --intrinsics auto, assume --fov instead of estimating the focal length from the video")
    g.add_argument("--no-cache", action="store_true",
                   help="do not keep tracks and computed priors in DIR/priors/ (by default a re-run reuses them)")
    r.add_argument("--method", default="trackingworld", choices=["trackingworld", "baseline"],
                   help="trackingworld (the full method) or baseline (camera-centric lifting, no optimisation)")
    r.add_argument("--device", default="cpu", help="cpu | cuda | cuda:N")
    r.add_argument("--max-frames", type=POSITIVE_INT, default=None)
    r.add_argument("--frame-stride", type=POSITIVE_INT, default=1)
    r.add_argument("--resize", type=_at_least(MIN_RESIZE), default=None, help="long side of the processing resolution")
    _track_args(r)
    _optim_args(r)
    r.add_argument("--quiet", action="store_true")

    k = sub.add_parser("track2d", help="dense 2D tracking of almost all pixels of all frames")
    k.add_argument("input", help="video file or folder of images")
    k.add_argument("--out", required=True, help="output .npz (tracks [N,T,2], visible, confidence, queries)")
    k.add_argument("--device", default="cpu")
    k.add_argument("--max-frames", type=POSITIVE_INT, default=None)
    k.add_argument("--frame-stride", type=POSITIVE_INT, default=1)
    k.add_argument("--resize", type=_at_least(MIN_RESIZE), default=None)
    _track_args(k)
    _threads_arg(k)
    k.add_argument("--quiet", action="store_true")

    e = sub.add_parser("eval", help="evaluate a result folder against a synthetic scene")
    e.add_argument("dir", help="result folder (holding result.npz)")
    e.add_argument("--gt", required=True, help="scene folder written by `trackingworld synth`")
    e.add_argument("--json", action="store_true", help="print the full metrics as JSON")

    v = sub.add_parser("view", help="open a result in the interactive 4D viewer (browser, localhost)")
    v.add_argument("dir", help="result folder (holding result.npz)")
    v.add_argument("--port", type=_at_least(0), default=8080)
    v.add_argument("--host", default="127.0.0.1", help="127.0.0.1 (default, this machine only) or 0.0.0.0")
    v.add_argument("--max-points", type=POSITIVE_INT, default=None,
                   help="points per frame sent to the browser (default 150000; the density slider goes lower)")
    v.add_argument("--video", help="input video or image folder, when it has moved since the run")

    from trackingworld.viz.render import COLOR_BY, VIEWS, RenderConfig

    d = RenderConfig()
    n = sub.add_parser("render", help="write shareable videos and plots into DIR/render/")
    n.add_argument("dir", help="result folder (holding result.npz)")
    n.add_argument("--only", nargs="+", choices=["tracks", "scene", "path"], default=["tracks", "scene", "path"],
                   help="tracks: tracks_2d.mp4, scene: scene_3d.mp4, path: camera_path.png (default: all)")
    n.add_argument("--color-by", default=d.color_by, choices=list(COLOR_BY),
                   help="colour of the 2D tracks (step: the step that set each label, the viewer's legend; object: "
                        "the rigid object that placed each track)")
    n.add_argument("--view", default=d.view, choices=VIEWS,
                   help="viewpoint of scene_3d.mp4: orbit (swings about the scene), follow (behind and above the "
                        "camera), input (the estimated camera itself) or fixed (--eye, --target)")
    n.add_argument("--eye", type=_xyz, help="fixed view: world position X,Y,Z of the viewpoint (metres)")
    n.add_argument("--target", type=_xyz, help="fixed view: world point X,Y,Z looked at (default: the scene's "
                   "median static point)")
    n.add_argument("--swing", type=float, default=d.swing_deg, help="orbit swing, degrees either side")
    n.add_argument("--elevation", type=float, default=d.elevation_deg, help="orbit/follow elevation, degrees")
    n.add_argument("--max-tracks", type=_at_least(0), default=d.max_tracks, help="2D tracks drawn per frame (about)")
    n.add_argument("--max-points", type=POSITIVE_INT, default=d.max_points, help="static points in the 3D video")
    n.add_argument("--fps", type=POSITIVE, default=d.fps)
    n.add_argument("--gt", help="synthetic scene folder: plot the camera path against its ground truth "
                   "(default: the scene of an earlier `trackingworld eval`, if any)")
    n.add_argument("--video", help="input video or image folder, when it has moved since the run")
    n.add_argument("--quiet", action="store_true")

    from trackingworld.io.export import FORMATS

    x = sub.add_parser("export", help="write a result in another tool's format (into DIR/export/)")
    x.add_argument("dir", help="result folder (holding result.npz)")
    x.add_argument("--format", required=True, choices=FORMATS)
    x.add_argument("--out", help="output file or folder (default: DIR/export/<name>)")
    x.add_argument("--max-points", type=POSITIVE_INT, default=None,
                   help="cap on exported tracks for colmap (default 100000), nerfstudio/ply (300000), rrd "
                   "(150000); tum and tapvid3d keep all")
    x.add_argument("--no-images", action="store_true", help="colmap/nerfstudio: do not write the frames")
    x.add_argument("--video", help="input video or image folder, when it has moved since the run")
    x.add_argument("--quiet", action="store_true")
    return p


def _track_args(p) -> None:
    from trackingworld.config import UPSAMPLERS, Track2DConfig

    g = p.add_argument_group("2D tracking")
    g.add_argument("--tracks", help="precomputed tracks .npz (CoTracker or TAPNet layout) instead of tracking")
    g.add_argument("--tracker", default="flow", choices=["flow", "cotracker3"],
                   help="sparse tracker under the dense machinery: flow (weight-free, default) or cotracker3")
    g.add_argument("--cotracker", default="cotracker3",
                   help="cotracker3 (torch hub, downloads once) | hub:REPO_OR_DIR[:ENTRY] | a .pth checkpoint")
    g.add_argument("--grid-stride", type=POSITIVE_INT, default=4, help="stride s of the tracked grid (px)")
    g.add_argument("--query-stride", type=POSITIVE_INT, default=1, help="track from every k-th frame (authors: 10)")
    g.add_argument("--first-frame-only", action="store_true", help="ablation: no tracking every frame")
    g.add_argument("--cover-radius", type=NON_NEGATIVE, default=1.0, help="r: px within which a pixel is covered")
    g.add_argument("--min-component", type=_at_least(0), default=50, help="tau: smallest new component (px)")
    g.add_argument("--dense-mode", default="upsample", choices=["upsample", "direct"])
    g.add_argument("--upsampler", default="convex", choices=UPSAMPLERS,
                   help="convex: weighted affine fit of the grid neighbours at each pixel; convex-mean: their "
                        "weighted mean (the paper)")
    g.add_argument("--flow-preset", default="fine", choices=["ultrafast", "fast", "medium", "fine"])
    g.add_argument("--flow-patch", type=_patch, default=Track2DConfig().flow_patch, metavar="SIZE,STRIDE",
                   help="the fine preset's DIS patch side and stride in px (smaller patches leak less of a mover's "
                        "flow into the background beside it; 8,3 before)")
    g.add_argument("--flow-skip-stride", type=int, default=4,
                   help="flows this many frames apart re-place the points chained one frame at a time (0: off)")
    g.add_argument("--flow-drag-px", type=float, default=0.5, metavar="PX",
                   help="a step near a motion boundary that leaves the median step of the neighbours that moved like "
                        "the point by more than PX + 10%% is not observed: a point dragged along by an object passing "
                        "it (0: off)")
    g.add_argument("--flow-median", type=int, default=Track2DConfig().flow_median, metavar="PX",
                   help="each optical flow through a weighted median of this radius guided by the frame's colours, "
                        "which puts motion boundaries back on colour edges (0: off; needs opencv-contrib)")
    g.add_argument("--flow-refind-patch-diff", type=float, default=Track2DConfig().flow_refind_patch_diff,
                   metavar="GREY", help="a point found again after a gap must look like its 5x5 patch in its query "
                                        "frame within GREY grey levels (mean absolute difference, patch means "
                                        "removed), or it stays hidden (0: off, the default)")


def _track_config(a):
    from trackingworld.config import Track2DConfig

    return Track2DConfig(
        tracker="file" if a.tracks else a.tracker, cotracker=a.cotracker, tracks_file=a.tracks,
        grid_stride=a.grid_stride,
        query_stride=a.query_stride, first_frame_only=a.first_frame_only, cover_radius=a.cover_radius,
        min_component=a.min_component, dense_mode=a.dense_mode, upsampler=a.upsampler, flow_preset=a.flow_preset,
        flow_patch=a.flow_patch, flow_skip_stride=a.flow_skip_stride, flow_drag_px=a.flow_drag_px,
        flow_median=a.flow_median, flow_refind_patch_diff=a.flow_refind_patch_diff)


def _threads_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--threads", type=POSITIVE_INT, default=None, metavar="N",
                   help="at most N threads in each pool of the process (torch, OpenCV, the frame loops; default: "
                        "every CPU). Runs that share a machine need N x runs <= cores: more threads than cores make "
                        "torch's threads wait on each other, many times slower")


def _apply_threads(a) -> None:
    """``--threads``: the process's thread cap (optim.parallel.set_thread_cap; argparse refuses below 1)."""
    if a.threads is None:
        return
    from trackingworld.optim.parallel import set_thread_cap

    set_thread_cap(a.threads)


def cmd_track2d(a) -> int:
    import numpy as np

    from trackingworld.config import InputConfig
    from trackingworld.io.atomic import check_writable, write_npz
    from trackingworld.pipeline.inputs import load_inputs
    from trackingworld.pipeline.tracks import check_track2d, track_video

    _apply_threads(a)
    cfg = _track_config(a)
    check_track2d(cfg)  # before the video is read
    check_writable(Path(a.out).parent, "folder of the tracks file")
    if Path(a.out).is_dir():
        raise InputError(f"{a.out}: is a folder; --out names the tracks file (.npz)")
    inp = load_inputs(InputConfig(input=a.input, max_frames=a.max_frames, frame_stride=a.frame_stride,
                                  resize=a.resize), verbose=not a.quiet)
    tr = track_video(inp.frames, cfg, None, a.device, verbose=not a.quiet)
    q = tr.queries.copy()
    q[:, 1:] = inp.to_input_pixels(tr.queries[:, 1:])
    write_npz(a.out, tracks=inp.to_input_pixels(tr.tracks), visible=tr.visible,
              confidence=tr.confidence.astype(np.float16), queries=q, size=np.array(inp.size_in))
    print(f"{len(tr.queries)} tracks x {tr.visible.shape[1]} frames written to {a.out}")
    return 0


ABLATIONS = {
    "no_pose_init": "w/o pose initialisation (stage 1 skipped, identity poses)",
    "no_inliers": "w/o inlier selection in stage 1",
    "no_offsets": "w/o the offsets O_static (plain least squares in stage 2, no moving-background test)",
    "no_depth_consistency": "w/o the depth consistency loss (stages 2 and 3)",
    "no_dynamic_opt": "w/o dynamic object tracking (dynamic tracks lifted with the raw prior)",
}


def _optim_args(p: argparse.ArgumentParser) -> None:
    from trackingworld.config import (
        CARRY_STATS,
        DC_TARGETS,
        FIELD_ORDERS,
        REFINE_FOCAL,
        STAGE3_LINEAR,
        STATIC_REBUILDS,
        TS_ORDERS,
        VOTE_CORE,
        OptimConfig,
    )

    d = OptimConfig()
    g = p.add_argument_group("world-centric optimisation (defaults: the paper's values)")
    g.add_argument("--solver", default=d.solver, choices=["lm", "adam"],
                   help="lm: structured Gauss-Newton/Levenberg-Marquardt (fast); adam: the paper's schedule")
    g.add_argument("--clip-len", type=_at_least(2), default=d.clip_len)
    g.add_argument("--inlier-px", type=POSITIVE, default=d.inlier_px, help="stage-1 inlier threshold tau (px)")
    g.add_argument("--epsilon", type=POSITIVE, default=d.epsilon,
                   help="offset that marks a moving background (metres, in the depth prior's units: with --depth "
                        "sfm the median depth is 1)")
    g.add_argument("--offset-stat", type=_offset_stat, default=d.offset_stat,
                   help="statistic of a track's offset norms compared with epsilon: max (the paper) or pNN, a "
                        "percentile (p50 with --epsilon 0.05: fewer drifting static tracks called moving)")
    g.add_argument("--test-stat", type=_offset_stat, default=d.test_stat,
                   help="(not in the paper) the same statistic in the as-static test of the tracks outside the bundle "
                        "adjustment, poses held (default p75: a static track may leave its point in a quarter of its "
                        "frames, which are then left out, see --static-outliers; max: the paper)")
    g.add_argument("--refine-focal", default=d.refine_focal, choices=REFINE_FOCAL,
                   help="refine the focal length in stage 2 (auto: when --intrinsics is not given and the depth prior "
                        "is not constant)")
    g.add_argument("--lambda-ba", type=NON_NEGATIVE, default=d.lambda_ba, help="reprojection weight (stages 2, 3)")
    g.add_argument("--lambda-dc", type=NON_NEGATIVE, default=d.lambda_dc, help="depth-consistency weight (stages 2, 3)")
    g.add_argument("--ba-dc-weight", type=NON_NEGATIVE, default=d.ba_dc_weight, metavar="X",
                   help="stage 2's bundle adjustment weighs the depth term by --lambda-dc times this (below 1: the "
                        "parallax trusted over the prior's shape)")
    g.add_argument("--ba-dc-parallax", type=float, default=d.ba_dc_parallax_rad, metavar="RAD",
                   help="stage 2's depth term per point times p0^2 / (p0^2 + a^2), a the angle (rad) its first and "
                        "last cameras see it under, p0 this: points seen from far apart placed by their parallax "
                        "(0: every point alike, the paper)")
    g.add_argument("--lambda-asap", type=NON_NEGATIVE, default=d.lambda_asap)
    g.add_argument("--lambda-arap", type=NON_NEGATIVE, default=d.lambda_arap)
    g.add_argument("--lambda-ts", type=NON_NEGATIVE, default=d.lambda_ts)
    g.add_argument("--ts-order", type=int, default=d.ts_order, choices=TS_ORDERS,
                   help="stage-3 temporal smoothness: 2 = second difference, constant velocity is free (default); "
                        "1 = first difference, a zero-velocity prior (the paper)")
    g.add_argument("--stage3-linear", default=d.stage3_linear, choices=STAGE3_LINEAR,
                   help="stage 3's linear solve (lm solver): cg = Jacobi-preconditioned CG on the sparse normal "
                        "equations, on the run's device (default) | amg = multigrid-preconditioned CG (pyamg, CPU)")
    g.add_argument("--dc-target", default=d.dc_target, choices=DC_TARGETS,
                   help="stage-3 depth target: the raw prior (the paper), the prior times each frame's static "
                        "z / prior median, that ratio propagated from the nearest static tracks, or a robust "
                        "smooth field of it over the image (default)")
    g.add_argument("--dc-target-smooth", type=float, default=d.dc_target_smooth, metavar="W",
                   help="with --dc-target field: the weight of the field's smoothness (larger: stiffer)")
    g.add_argument("--dc-target-order", type=int, choices=FIELD_ORDERS, default=d.dc_target_order,
                   help="stage 3's target field's smoothness penalty: 1 first differences (a hole under a mover is "
                        "filled flat), 2 the thin-plate energy (its slopes continue under it)")
    g.add_argument("--dc-field-smooth", type=float, default=d.dc_field_smooth, metavar="W",
                   help="the static side's correction fields of the prior (the static tracks' corrected prior, the "
                        "depth-mover test): the weight of their smoothness")
    g.add_argument("--dc-field-temporal", type=float, default=d.dc_field_temporal, metavar="W",
                   help="with --dc-target field: hold each frame's field near its neighbours' in time with this "
                        "weight (0: each frame on its own, as before)")
    g.add_argument("--dc-edge-sigma", type=float, default=d.dc_edge_sigma_px, metavar="PX",
                   help="(not in the paper) the prior on the static tracks (stages 1-2) and on the dynamic tracks "
                        "(stage 3) averaged over each side's own pixels away from the prior's blurred depth edges, "
                        "with a Gaussian of this many px (0: the prior as sampled)")
    g.add_argument("--carry-k", type=int, default=d.carry_k,
                   help="hidden frames of dynamic tracks follow the motion of this many nearby tracks visible both "
                        "there and in the track's nearest visible frame (0: held)")
    g.add_argument("--carry-reach", type=float, default=d.carry_reach, metavar="M",
                   help="with --carry-k: leave out the tracks farther than this many metres (and than twice the "
                        "nearest one's distance) from the hidden track, on another object")
    g.add_argument("--carry-motion", type=float, default=d.carry_motion_frames, metavar="FRAMES",
                   help="with --carry-k: nearness also in 2D velocity, 1 px/frame of difference counting as the "
                        "drift of this many frames at the dynamic tracks' median depth (0: 3D distance alone)")
    g.add_argument("--carry-stat", choices=CARRY_STATS, default=d.carry_stat,
                   help="with --carry-k: the donors' steps combined by their weighted median per coordinate (a donor "
                        "on another object does not drag the step along) or weighted mean")
    g.add_argument("--mask-dynamic-px", type=float, default=d.mask_dynamic_px,
                   help="a track in the dynamic mask is static only if its static fit's largest reprojection "
                        "residual is at most this many px (0: the offset test alone)")
    g.add_argument("--mask-core-px", type=float, default=d.mask_core_px, metavar="PX",
                   help="(not in the paper) a track whose query pixel lies this deep inside the coarse mask or deeper "
                        "keeps the masks' dynamic label, untested and not voted on (the static points a dilated mask "
                        "covers lie in a band along its border; 0: every masked track gets the as-static test and "
                        "the short ones the vote; default %(default)s)")
    g.add_argument("--slip-run", type=float, default=d.slip_run, metavar="FRAC",
                   help="(not in the paper) a masked or ambiguous track, or one the vote calls moving, that fails the "
                        "static test is static when "
                        "the point fitted around its query frame holds over a run of at least this fraction of "
                        "its visible frames (then dragged off by a mover: the rest is left out; 0: off)")
    g.add_argument("--slip-px", type=float, default=d.slip_px,
                   help="with --slip-run: the run's reprojection bound (px; --mask-dynamic-px in the dynamic mask)")
    g.add_argument("--depth-mover", type=float, default=d.depth_mover_log, metavar="LOG",
                   help="static tracks whose fitted depth disagrees with the prior by this much (log units) in a "
                        "local majority of most of their frames become dynamic: movers along the epipolar lines "
                        "that the masks missed (0: off, the paper)")
    g.add_argument("--depth-mover-window", type=float, default=d.depth_mover_window_px, metavar="PX",
                   help="side of the square (px) of that local majority")
    g.add_argument("--depth-mover-bin", type=float, default=d.depth_mover_bin, metavar="LOG",
                   help="(not in the paper) an observation also wins by the majority of the observations in its "
                        "square whose prior depth lies in its bin of this width (log units) or the two beside it: a "
                        "mover too small to fill the square (0: the square alone, before stop 91)")
    g.add_argument("--depth-mover-bin-factor", type=float, default=d.depth_mover_bin_factor, metavar="X",
                   help="(not in the paper) with --depth-mover-bin: an observation wins by the square's majority at "
                        "the threshold or by its depth's at X times it (0: by its depth's alone, at the threshold)")
    g.add_argument("--depth-mover-mad", type=float, default=d.depth_mover_mad, metavar="K",
                   help="(not in the paper) the depth-discrepancy test's threshold raised to K times the median "
                        "absolute deviation of the discrepancies when that is larger (0: the fixed threshold)")
    g.add_argument("--depth-mover-max-share", type=float, default=d.depth_mover_max_share, metavar="SHARE",
                   help="(not in the paper) the depth-discrepancy test's flags dropped when they are more than this "
                        "share of the tracks it tests: the prior is then wrong over much of the scene (0: no cap, "
                        "the default for a given prior; an estimated one, SfM or a depth model, gets 0.08)")
    g.add_argument("--depth-mover-rounds", type=int, default=d.depth_mover_rounds, metavar="N",
                   help="rounds of that test, each against the frames' fields fitted again without the movers and "
                        "suspects the last round found")
    g.add_argument("--depth-mover-suspect", type=float, default=d.depth_mover_suspect, metavar="FRAC",
                   help="tracks that pass the test at this fraction of --depth-mover are left out of the next "
                        "round's fields without being called movers (1: the movers only)")
    g.add_argument("--depth-mover-range", type=_range_px, default=d.depth_mover_range_px, metavar="auto|PX",
                   help="measure each discrepancy to the nearest of the prior at the pixel and its farthest and "
                        "nearest values within this many px (the prior's blur at depth edges; 0: the pixel's value; "
                        "auto, the default: the prior's edge blur, estimated, 1-4 px)")
    g.add_argument("--stage2-reject", action=argparse.BooleanOptionalAction, default=d.stage2_reject,
                   help="(not in the paper) stage 2 solved again without the observations whose offset reached "
                        "epsilon (a moving object's pull on the poses); --no-stage2-reject: one solve, the paper")
    g.add_argument("--static-outliers", action=argparse.BooleanOptionalAction, default=d.static_outliers,
                   help="(not in the paper) a static track's observations whose offset reaches epsilon are left out "
                        "of its point's final fit and marked not visible (frames where its 2D track left the point)")
    g.add_argument("--own-test", action=argparse.BooleanOptionalAction, default=d.own_test,
                   help="a static track its optimised neighbours call moving is moving only if its own as-static "
                        "test fails too; a track seen once takes its tested neighbours' verdict (default); "
                        "--no-own-test: the neighbours' vote alone (the appendix)")
    g.add_argument("--vote-colour-sigma", type=float, default=d.vote_colour_sigma, metavar="GREY",
                   help="(not in the paper) a track seen once takes its tested neighbours' vote weighted also by "
                        "a Gaussian of this width in their colour difference (0: by the prior-lifted distance alone)")
    g.add_argument("--vote-k", type=int, default=d.vote_k, help="voters of that colour-weighted vote")
    g.add_argument("--vote-short", type=int, default=d.vote_short, metavar="FRAMES",
                   help="(not in the paper; with --own-test) a track seen in at most this many frames, too short to "
                        "fail the static test, takes the vote of the tracks seen in more (1: the tracks seen once)")
    g.add_argument("--vote-once-gap", type=float, default=d.vote_once_gap_px, metavar="PX",
                   help="(not in the paper) a track seen once with none of its voters (tracks seen in more than "
                        "--vote-short frames) within PX takes the vote of every track seen in two frames or more "
                        "(inf: off)")
    g.add_argument("--vote-core", default=d.vote_core, choices=VOTE_CORE,
                   help="(not in the paper) the masks' cores (--mask-core-px) not voted on by the vote of the short "
                        "tracks (auto: with masks of objects, a file or a segmentation model; not with the weight-free "
                        "motion masks)")
    g.add_argument("--vote-flip-px", type=float, default=d.vote_flip_px, metavar="PX",
                   help="with --vote-short: the vote makes a short track dynamic only when its static fit misses a "
                        "pixel by more than this (0: always)")
    g.add_argument("--photo-static", type=float, default=d.photo_static_grey, metavar="GREY",
                   help="(not in the paper) a dynamic track is a static point its 2D track was dragged off when that "
                        "point shows its query colour within this many grey levels in most frames where it lies "
                        "outside the masks (0: off)")
    g.add_argument("--photo-static-frac", type=float, default=d.photo_static_frac, metavar="FRAC",
                   help="with --photo-static: the share of those frames that must match")
    g.add_argument("--photo-static-range", type=float, default=d.photo_static_range, metavar="FRAC",
                   help="with --photo-static: the depths tried, the corrected prior's times 1 +- this (steps of 0.02)")
    g.add_argument("--photo-static-near", type=float, default=d.photo_static_near_px, metavar="PX",
                   help="with --photo-static: the tracks of the masks' static region seen within this many px of the "
                        "masks are tested too (0: only the masks' dynamic and ambiguous tracks)")
    g.add_argument("--photo-static-hidden", action=argparse.BooleanOptionalAction, default=d.photo_static_hidden,
                   help="with --photo-static: the frames where a nearer surface of the video depth hides the point "
                        "are not tested (default); --no-photo-static-hidden: they are")
    g.add_argument("--photo-static-patch", type=float, default=d.photo_static_patch, metavar="GREY",
                   help="with --photo-static: a frame matches only where the 5x5 patch at the point (its mean "
                        "removed) is within this many grey levels of the query patch on the mean (0: the colour "
                        "alone)")
    g.add_argument("--photo-static-track", type=float, default=d.photo_static_track_px, metavar="PX",
                   help="with --photo-static: a frame where the track is seen more than PX from the point's "
                        "projection matches only where the projection shows the query colour better than the "
                        "track's own pixel (0: the projection alone)")
    g.add_argument("--rigid-movers", action=argparse.BooleanOptionalAction, default=d.rigid_movers,
                   help="(not in the paper; on by default) after stage 3, place each group of dynamic tracks that "
                        "one rigid motion explains by that motion, fitted to their 2D tracks and, for its scale, to "
                        "the depth targets of all frames; --no-rigid-movers: stage 3's positions, as the paper")
    g.add_argument("--rigid-bridge", action=argparse.BooleanOptionalAction, default=d.rigid_bridge,
                   help="(not in the paper; on by default) with --rigid-movers: join the groups of one object on "
                        "either side of a gap in its tracks (hidden for a few frames), so that each group's tracks "
                        "follow the object on the other side too; --no-rigid-bridge: each group in its own frames")
    g.add_argument("--rigid-second-pass", type=int, default=d.rigid_second_pass, metavar="SEEDS",
                   help="(not in the paper) with --rigid-movers: a second search for groups, of at most SEEDS seeds, "
                        "each kept away from the patches the first search tried (0: one search)")
    g.add_argument("--rigid-split-gap", type=float, default=d.rigid_split_gap, metavar="FRAC",
                   help="(not in the paper) with --rigid-movers: a group whose points fall apart, in the object's "
                        "frame, into pieces more than FRAC x their median depth apart is cut to its largest piece "
                        "(0: never)")
    g.add_argument("--rigid-relay-gap", type=float, default=d.rigid_relay_gap, metavar="FRAC",
                   help="(not in the paper) with --rigid-movers: a group whose tracks fall into an earlier and a later "
                        "set that hardly a track spans, their points nowhere within FRAC x their median depth of "
                        "each other, is two objects handed over and is cut to its larger set (0: never)")
    g.add_argument("--rigid-key-frames", type=int, default=d.rigid_key_frames, metavar="FRAMES",
                   help="(not in the paper) with --rigid-movers: a group's motion solved in more frames than FRAMES "
                        "is bundle-adjusted on FRAMES key frames spread over them and every other frame's pose "
                        "fitted to its points (0: all frames in the bundle adjustment)")
    g.add_argument("--occluded-static", type=int, default=d.occluded_static_frames, metavar="FRAMES",
                   help="(not in the paper) a dynamic track is its query pixel's static point when it is on that "
                        "point wherever the point is in view and off it in at least FRAMES frames where a nearer "
                        "surface hides the point (0: off)")
    g.add_argument("--occluded-static-frac", type=float, default=d.occluded_static_frac, metavar="FRAC",
                   help="with --occluded-static: the share of the in-view frames where the track must be on the "
                        "point")
    g.add_argument("--occluded-static-in-view", type=int, default=d.occluded_static_in_view, metavar="FRAMES",
                   help="with --occluded-static: the point must be in view in at least this many of the track's "
                        "frames (its query frame aside)")
    g.add_argument("--occluded-static-px", type=float, default=d.occluded_static_px, metavar="PX",
                   help="with --occluded-static: on the point means within this many px of its projection")
    g.add_argument("--occluded-static-depth", type=float, default=d.occluded_static_depth, metavar="RATIO",
                   help="with --occluded-static: the point is hidden where the video depth is less than this times "
                        "the point's")
    g.add_argument("--photo-moving", type=float, default=d.photo_moving_share, metavar="SHARE",
                   help="(not in the paper) a short static track of the masks' static region whose static point shows "
                        "its query colour in less than this share of the frames where it should be seen is a mover "
                        "the masks missed (labels only; 0: off; default %(default)s)")
    g.add_argument("--prior-field", action=argparse.BooleanOptionalAction, default=d.prior_field,
                   help="static tracks outside stage 2 are fitted against the prior corrected by the field of the "
                        "optimised static points' z / prior (default); --no-prior-field: the raw prior")
    g.add_argument("--static-refit-dc", type=float, default=d.static_refit_dc, metavar="LAMBDA",
                   help="refit every static point against that corrected prior with this depth weight after the "
                        "depth-mover test (0: off, the paper)")
    g.add_argument("--static-rebuild", default=d.static_rebuild, choices=STATIC_REBUILDS,
                   help="static tracks not optimised: triangulated with the poses held (fit) or rebuilt on "
                        "their query ray at the IDW-propagated depth (idw, the paper's appendix)")
    g.add_argument("--static-fit-frames", type=int, default=d.static_fit_frames, metavar="N",
                   help="each static fit outside stage 2 reads at most about N of the track's visible frames, spread "
                        "over its span (0: all)")
    g.add_argument("--downsample-cell", type=int, default=d.downsample_cell,
                   help="optimise one static track per cell of this many px (0: all)")
    g.add_argument("--dynamic-cell", type=int, default=d.dynamic_cell, metavar="PX",
                   help="stage 3 solves one dynamic track per cell of this many px, the others follow it (0: all)")
    g.add_argument("--cell-cap", type=int, default=d.cell_cap,
                   help="optimise at most this many tracks' observations per frame and cell (0: all, the paper)")
    for name, text in ABLATIONS.items():
        g.add_argument("--" + name.replace("_", "-"), action="store_true", help=text)


def _optim_config(a):
    from trackingworld.config import OptimConfig

    return OptimConfig(
        solver=a.solver, clip_len=a.clip_len, inlier_px=a.inlier_px, epsilon=a.epsilon, offset_stat=a.offset_stat,
        test_stat=a.test_stat, static_outliers=a.static_outliers, stage2_reject=a.stage2_reject,
        lambda_ba=a.lambda_ba, lambda_dc=a.lambda_dc, ba_dc_weight=a.ba_dc_weight,
        ba_dc_parallax_rad=a.ba_dc_parallax,
        lambda_asap=a.lambda_asap, lambda_arap=a.lambda_arap, lambda_ts=a.lambda_ts, ts_order=a.ts_order,
        stage3_linear=a.stage3_linear,
        dc_target=a.dc_target, dc_target_smooth=a.dc_target_smooth, dc_field_smooth=a.dc_field_smooth,
        dc_target_order=a.dc_target_order,
        dc_field_temporal=a.dc_field_temporal, dc_edge_sigma_px=a.dc_edge_sigma,
        carry_k=a.carry_k, carry_reach=a.carry_reach, carry_motion_frames=a.carry_motion,
        carry_stat=a.carry_stat,
        mask_dynamic_px=a.mask_dynamic_px, mask_core_px=a.mask_core_px, slip_run=a.slip_run, slip_px=a.slip_px,
        static_rebuild=a.static_rebuild, static_fit_frames=a.static_fit_frames,
        depth_mover_log=a.depth_mover, depth_mover_window_px=a.depth_mover_window,
        depth_mover_bin=a.depth_mover_bin, depth_mover_bin_factor=a.depth_mover_bin_factor,
        depth_mover_rounds=a.depth_mover_rounds, depth_mover_mad=a.depth_mover_mad,
        depth_mover_max_share=a.depth_mover_max_share,
        depth_mover_suspect=a.depth_mover_suspect,
        depth_mover_range_px=a.depth_mover_range,
        own_test=a.own_test, vote_colour_sigma=a.vote_colour_sigma, vote_k=a.vote_k, vote_short=a.vote_short,
        vote_once_gap_px=a.vote_once_gap, vote_core=a.vote_core,
        vote_flip_px=a.vote_flip_px, photo_static_grey=a.photo_static, photo_static_frac=a.photo_static_frac,
        photo_static_near_px=a.photo_static_near, photo_static_range=a.photo_static_range,
        photo_static_hidden=a.photo_static_hidden, photo_static_patch=a.photo_static_patch,
        photo_static_track_px=a.photo_static_track,
        rigid_movers=a.rigid_movers, rigid_bridge=a.rigid_bridge, rigid_second_pass=a.rigid_second_pass,
        rigid_split_gap=a.rigid_split_gap, rigid_relay_gap=a.rigid_relay_gap,
        rigid_key_frames=a.rigid_key_frames,
        occluded_static_frames=a.occluded_static, occluded_static_frac=a.occluded_static_frac,
        occluded_static_in_view=a.occluded_static_in_view, photo_moving_share=a.photo_moving,
        occluded_static_px=a.occluded_static_px, occluded_static_depth=a.occluded_static_depth,
        prior_field=a.prior_field, static_refit_dc=a.static_refit_dc, refine_focal=a.refine_focal,
        downsample_cell=a.downsample_cell, dynamic_cell=a.dynamic_cell, cell_cap=a.cell_cap, verbose=not a.quiet,
        **{k: getattr(a, k) for k in ABLATIONS})


def cmd_synth(a) -> int:
    from trackingworld.io.atomic import check_writable
    from trackingworld.synth import render_and_write

    check_writable(a.out, "scene folder")
    try:
        out = render_and_write(a.out, a.preset, a.seed, a.frames, a.size, fov_deg=a.fov, grounded_movers=a.grounded)
    except ValueError as e:
        raise InputError(f"synth --preset {a.preset} --seed {a.seed}: {e}") from e
    print(f"scene written to {out} (inputs in {out / 'input'}, ground truth in {out / 'gt.npz'})")
    return 0


def cmd_run(a) -> int:
    from trackingworld.config import InputConfig, RunConfig
    from trackingworld.io.atomic import check_writable
    from trackingworld.pipeline.batch import SUMMARY_FILE, finished, run_batch, summary
    from trackingworld.pipeline.run import run

    check_writable(a.out)  # before any work: a result that cannot be written is lost at the end

    cfg = RunConfig(
        method=a.method, device=a.device,
        inputs=InputConfig(input=a.input[0], depth=a.depth, masks=a.masks, mask_prompt=a.mask_prompt,
                           intrinsics=a.intrinsics, max_frames=a.max_frames, frame_stride=a.frame_stride,
                           resize=a.resize, cache=not a.no_cache, default_fov_deg=a.fov,
                           self_calibrate=not a.no_self_calibration, sfm_contact=a.sfm_contact),
        track2d=_track_config(a), optim=_optim_config(a),
    )
    _apply_threads(a)
    if len(a.input) > 1:
        entries = run_batch(cfg, a.input, a.out, a.skip_done, verbose=not a.quiet, jobs=a.jobs, threads=a.threads)
        n = summary(entries, len(entries))
        print(f"{n['done']} done, {n['skipped']} skipped, {n['failed']} failed of {n['inputs']}: "
              f"{Path(a.out) / SUMMARY_FILE}")
        for e in entries:  # the input named once: most errors name their file already
            if e["status"] == "failed":
                where = "" if e["input"] in e["error"] else f" {e['input']}:"
                print(f"trackingworld run:{where} error: {e['error']}", file=sys.stderr)
        return 1 if n["failed"] else 0
    if a.skip_done and finished(Path(a.out)):
        print(f"{a.out} already holds a finished run; left as it is (--skip-done)")
        return 0
    run(cfg, a.out, verbose=not a.quiet)
    print(f"result written to {Path(a.out) / 'result.npz'}")
    return 0


def cmd_eval(a) -> int:
    from trackingworld.eval.evaluate import evaluate_to_file, format_table

    m = evaluate_to_file(a.dir, a.gt)
    if a.json:
        print(json.dumps(m, indent=2))
    else:
        print(format_table({Path(a.dir).name or "result": m}))
    print(f"metrics written to {Path(a.dir) / 'metrics.json'}")
    return 0


def cmd_view(a) -> int:
    from trackingworld.viz.viewer import serve

    serve(a.dir, port=a.port, host=a.host, video=a.video, max_points=a.max_points)
    return 0


def cmd_render(a) -> int:
    from trackingworld.viz.render import RenderConfig, render

    cfg = RenderConfig(color_by=a.color_by, view=a.view, eye=a.eye, target=a.target, swing_deg=a.swing,
                       elevation_deg=a.elevation, max_tracks=a.max_tracks, max_points=a.max_points, fps=a.fps)
    out = render(a.dir, cfg, gt=a.gt, video=a.video, what=tuple(a.only), verbose=not a.quiet)
    for p in out.values():
        print(p)
    return 0


def cmd_export(a) -> int:
    from trackingworld.io.export import export

    print(export(a.dir, a.format, a.out, a.max_points, a.video, images=not a.no_images, verbose=not a.quiet))
    return 0


NEGATIVE_LIST = re.compile(r"^-[0-9.][0-9.,eE+-]*$")  # "-100,100,160,120": a value, not an option


def joined_negative_values(argv: list[str]) -> list[str]:
    """``argv`` with each ``--option VALUE`` whose value starts with a minus sign and is a list of numbers written
    as ``--option=VALUE``: argparse takes ``-100,100,160,120`` for an option of its own (it knows only bare negative
    numbers) and would say "expected one argument" rather than what is wrong with the value."""
    out: list[str] = []
    for tok in argv:
        if out and NEGATIVE_LIST.match(tok) and out[-1].startswith("--") and "=" not in out[-1]:
            out[-1] = f"{out[-1]}={tok}"
        else:
            out.append(tok)
    return out


def main(argv: list[str] | None = None) -> int:
    p = build_parser()
    try:
        a = p.parse_args(joined_negative_values(sys.argv[1:] if argv is None else list(argv)))
    except SystemExit as e:  # argparse has printed its usage and error (or the help); its exit code
        return int(e.code or 0) if not isinstance(e.code, str) else 2
    if a.version:
        from trackingworld import __version__

        print(__version__)
        return 0
    if not a.cmd:
        p.print_help()
        return 2
    reuse_freed_memory()  # large temporary arrays reused rather than paged in again (trackingworld.memory)
    try:
        return {"synth": cmd_synth, "run": cmd_run, "eval": cmd_eval, "track2d": cmd_track2d, "view": cmd_view,
                "render": cmd_render, "export": cmd_export}[a.cmd](a)
    except InputError as e:
        print(f"trackingworld {a.cmd}: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # the file system refused (a folder that cannot be made, a full disk): one line, exit 1
        if e.filename is None:
            raise
        print(f"trackingworld {a.cmd}: error: {e.filename}: {e.strerror or e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
