"""``--method trackingworld``: dense 2D tracks -> stages 1-3 -> world-centric 3D tracks, poses, video depth.

:func:`optimise` runs the steps in order and times each: labels from the masks, stage 1, stage 2 (here), the
prior's correction fields (``pipeline.fields``), the static side (``pipeline.static_side``), stage 3 on the dynamic
tracks (``pipeline.dynamic``) and the video depth."""

from __future__ import annotations

import sys
import time
from contextlib import contextmanager
from dataclasses import replace
from functools import partial

import cv2
import numpy as np
import torch

from trackingworld.config import OPTIM_CHOICES, OptimConfig, RunConfig
from trackingworld.errors import InputError
from trackingworld.geometry import focal_length
from trackingworld.io.result import Result
from trackingworld.memory import release_freed_memory
from trackingworld.optim import lie, stage2
from trackingworld.optim.densify import cell_cap_mask, cell_representatives
from trackingworld.optim.label_steps import LabelSteps
from trackingworld.optim.labels import AMBIGUOUS, DYNAMIC, STATIC, depth_in_mask, label_tracks
from trackingworld.optim.parallel import worker_threads
from trackingworld.optim.stage1 import initial_poses, pose_support_warning, weak_frames
from trackingworld.optim.static_tests import moving_tracks
from trackingworld.pipeline.baseline import sample_colors
from trackingworld.pipeline.dynamic import place_dynamic, place_rigid
from trackingworld.pipeline.fields import (
    corrected_prior,
    depth_mover_test,
    edge_free_prior,
    mover_range_px,
    static_fields,
)
from trackingworld.pipeline.inputs import Inputs, resize_stack
from trackingworld.pipeline.lift import sample_maps
from trackingworld.pipeline.static_side import (
    StaticFits,
    classify_masked,
    drop_off_point,
    occlusion_rescue,
    photo_moving,
    photo_rescue,
    rebuild_static,
    vote_short_tracks,
)
from trackingworld.pipeline.video_depth import SearchAhead, video_depth
from trackingworld.priors.sources import intrinsics_given
from trackingworld.progress import stage_logger, warn
from trackingworld.tracking2d.base import TrackResult


@contextmanager
def timed(timings: dict, name: str, verbose: bool):
    """Add the wall time of the block to ``timings[name]`` (seconds), with a start / end line on stderr."""
    t0 = time.perf_counter()
    if verbose:
        print(f"[{name}] ...", file=sys.stderr, flush=True)
    yield
    dt = time.perf_counter() - t0
    timings[name] = timings.get(name, 0.0) + dt
    if verbose:
        print(f"[{name}] done in {dt:.1f} s", file=sys.stderr, flush=True)


REFIT_ITERS = 3  # Gauss-Newton steps of the static refit (held to the corrected prior: the same metrics as 6 to
# within 0.1 on seeds 0-3 and hard 0, half the time)
FOCAL_ROUNDS = 3  # most rounds of (stage-2 bundle adjustment, focal refinement)
FOCAL_TOL = 0.002  # stop when the focal length changes by less than this (relative)
FOCAL_CONTRACTION = 0.6  # ... or when a round's change is not at most this fraction of the previous one's
FOCAL_SETTLED = 0.02  # the last round's change must be below this for the refined focal length to be kept


def solve_stage2(R, t, X, p: stage2.BAProblem, cfg: OptimConfig, log=None):
    """Stage 2 by the configured solver (the paper's Adam schedule, or the structured Levenberg-Marquardt) from
    world-to-camera poses R [T,3,3], t [T,3] and points X [N,3] world metres; with ``cfg.stage2_reject`` (not in
    the paper) solved again without the observations whose offset reached epsilon: nearly every residual sits in
    the L1 part of the offsets' kernel, where a moving object's observations pull on the poses as hard as the
    static ones, and all in one direction. Returns (solution, the problem solved last, observations rejected)."""
    def solve(R, t, X, p):
        if cfg.solver == "adam":
            return stage2.solve_adam(R, t, X, p, cfg.adam_iters[1], cfg.adam_lr, log)
        return stage2.solve_lm(R, t, X, p, cfg.lm_iters, cfg.lm_tol, log)

    sol = solve(R, t, X, p)
    if not (cfg.stage2_reject and p.offsets):
        return sol, p, 0
    inlier = stage2.offset_norms(sol.R, sol.t, sol.X, p) < cfg.epsilon
    rejected = int((~inlier).sum())
    if rejected:
        p = p.subset(inlier)
        sol = solve(sol.R, sol.t, sol.X, p)
    return sol, p, rejected


def capped_movers(movers: np.ndarray, cap: float, info: dict) -> np.ndarray:
    """The depth-discrepancy test's flags ``movers [n]`` (bool, one per track it tested), or none of them where they
    are more than ``cap`` of those tracks (0: no cap; ``OptimConfig.depth_mover_max_share``): a prior that disagrees
    with the static fits over that much of the scene is wrong there, not crossed by movers. What was dropped goes to
    ``info["depth_movers_dropped"]``."""
    if len(movers) and 0 < cap < movers.mean():
        info["depth_movers_dropped"] = {"flagged": int(movers.sum()), "tested": int(len(movers)), "cap": cap}
        return np.zeros_like(movers)
    return movers


def optimise(tr: TrackResult, prior: np.ndarray, masks: np.ndarray, K: np.ndarray, cfg: OptimConfig,
             timings: dict, device: str = "cpu", seed: int = 0, refine_focal: bool = False,
             colours: np.ndarray | None = None, frames: np.ndarray | None = None) -> dict:
    """Stages 1-3 on dense tracks ``tr`` (processing resolution), the depth prior ``[T,h,w]`` metres, the
    coarse masks ``[T,h,w]`` and K ``[3,3]``; ``refine_focal``: the focal length is refined in stage 2;
    ``colours`` [N,3] uint8: each track's RGB at its query pixel (the vote of the short tracks; None: that
    vote by distance alone); ``frames [T,h,w,3]`` uint8 at the processing resolution (the dynamic tracks' static
    hypothesis checked in the images, ``optim.photo_static``; None: not checked). Returns a
    dict with ``poses_c2w [T,4,4]``, ``xyz [N,T,3]`` world metres, ``is_dynamic [N]``, ``labels [N]`` (mask
    labels), ``depth [T,h,w]`` consistent video depth, ``K [3,3]`` (refined or as given), ``visible [N,T]``,
    ``tracks_2d [N,T,2]`` px (the tracks as given, except those the photometric test made static points: their
    points' projections) and ``info`` (losses, counts)."""
    tm = partial(timed, timings, verbose=cfg.verbose)
    log = stage_logger(cfg.verbose, every=5)
    rng = np.random.default_rng(seed)
    dtype = getattr(torch, cfg.dtype)
    uv, vis = tr.tracks.astype(np.float32, copy=False), tr.visible  # pixels: float32 is 1e-4 px
    N, T = vis.shape
    qf = tr.queries[:, 0].astype(np.int64)
    info: dict = {"tracks": int(N)}
    with tm("labels"):
        D = sample_maps(prior, tr.tracks, vis)  # float32 metres, 1 where hidden (never read)
        labels = label_tracks(tr.tracks, vis, qf, masks, cfg.mask_margin_px)
        static_idx = np.flatnonzero(labels == STATIC)
        # the depth the stages read: on the static tracks away from the depth edges (optim.edge_prior); the video
        # depth reads the raw prior at its references itself
        if cfg.dc_edge_sigma_px > 0 and len(static_idx):
            D = edge_free_prior(prior, uv, vis, static_idx, cfg.dc_edge_sigma_px, D, in_place=True)
        reps = static_idx[cell_representatives(tr.queries[static_idx], cfg.downsample_cell)]
        # the observations the stages optimise: all of these tracks' (the paper) or a capped number per frame
        obs = cell_cap_mask(tr.tracks[reps], vis[reps], qf[reps], cfg.downsample_cell, cfg.cell_cap)
        keep = obs.sum(1) >= 2
        s2, obs2 = reps[keep], obs[keep]
        info.update(static=int(len(static_idx)), dynamic_masks=int((labels == DYNAMIC).sum()),
                    ambiguous=int((labels == AMBIGUOUS).sum()), optimised_static=int(len(s2)))

    # frames whose pose the static tracks cannot place: said once, in optim.json too
    info["pose_warning"] = pose_support_warning(weak_frames(obs2), T, len(static_idx), N)
    warn(info["pose_warning"], cfg.verbose, "stage1")
    with tm("stage1"):
        if cfg.no_pose_init or len(s2) == 0:
            poses = np.tile(np.eye(4), (T, 1, 1))
        else:
            poses, info["stage1"] = initial_poses(uv[s2], D[s2], obs2, K, cfg, rng, device, log)

    with tm("stage2"):
        cfg_ba = replace(cfg, lambda_dc=cfg.lambda_dc * cfg.ba_dc_weight)  # the bundle adjustment's depth weight
        w_pt = None  # each point's factor on the depth term (OptimConfig.ba_dc_parallax_rad)
        if cfg.ba_dc_parallax_rad > 0 and len(s2):
            w_pt = torch.as_tensor(stage2.parallax_weights(uv[s2], D[s2], obs2, qf[s2], poses, K,
                                                           cfg.ba_dc_parallax_rad), dtype=dtype, device=device)
            info["stage2_dc_weight_median"] = float(w_pt.median())

        def ba_problem(obs):
            """Stage 2's problem over the control tracks' observations ``obs [len(s2),T]``, with the current K
            and each point's depth-term factor."""
            q = stage2.BAProblem.from_tracks(uv[s2], D[s2], obs, K, cfg_ba, dtype, device)
            return q if w_pt is None else replace(q, dc_weight=w_pt[q.pt])

        p = ba_problem(obs2)
        R, t = lie.c2w_to_w2c(poses, dtype, device)
        X0 = stage2.init_points(R, t, p)
        loss0 = float(stage2.loss(R, t, X0, p))
        f_start = focal_length(K)
        X = X0
        # with refine_focal: rounds of (bundle adjustment, focal length from its static inliers) until the focal
        # length settles; the Adam reference gets one round (it is the slow path by design)
        rounds = (1 if cfg.solver == "adam" else FOCAL_ROUNDS) if refine_focal else 1
        history = [f_start]
        start = None  # the solution with the starting focal length, kept in case the refinement does not settle
        p_all = p  # every observation: the moving-background test reads them all
        rejected = 0
        for _ in range(rounds):
            sol, p, rejected = solve_stage2(R, t, X, p_all, cfg, log)
            R, t, X = sol.R, sol.t, sol.X
            moving_s2 = moving_tracks(R, t, X, p_all, cfg)
            if not refine_focal:
                break
            if start is None:
                start = (K, p, R, t, X, moving_s2)
            fsol = stage2.refine_focal(sol, p, moving_s2, iters=cfg.lm_iters, tol=min(cfg.lm_tol, 1e-6), log=log)
            K = fsol.K.cpu().numpy()
            p, p_all = replace(p, K=fsol.K), replace(p_all, K=fsol.K)
            R, t = fsol.R, fsol.t
            X = stage2.fit_points(R, t, p_all)  # every control track against the new focal length, poses held
            moving_s2 = moving_tracks(R, t, X, p_all, cfg)
            history.append(focal_length(K))
            if cfg.verbose:
                print(f"[stage2] focal length, round {len(history) - 1}: {history[-2]:.1f} -> {history[-1]:.1f} px",
                      file=sys.stderr, flush=True)
            steps = np.abs(np.diff(np.log(history)))
            if steps[-1] < FOCAL_TOL or (len(steps) > 1 and steps[-1] > FOCAL_CONTRACTION * steps[-2]):
                break
        settled = not refine_focal or steps[-1] < FOCAL_SETTLED
        if not settled:  # the video does not pin the focal length down: keep the start
            K, p, R, t, X, moving_s2 = start
            if cfg.verbose:
                print(f"[stage2] the focal length did not settle ({' -> '.join(f'{f:.0f}' for f in history)} px): "
                      f"kept {f_start:.1f} px", file=sys.stderr, flush=True)
        # the loss of the problem solved last (without the rejected observations)
        info["stage2"] = {"loss_init": loss0, "loss": float(stage2.loss(R, t, X, p)), "rejected": rejected}
        if refine_focal:
            info["stage2"]["focal"] = {"initial_px": f_start, "refined_px": focal_length(K),
                                       "rounds_px": history, "settled": bool(settled)}
        if not np.array_equal(obs2, vis[s2]):  # capped: the moving-background test on every observation
            full = ba_problem(vis[s2])
            moving_s2 = moving_tracks(R, t, X, replace(full, K=p.K, kernel_focal=p.kernel_focal), cfg)
        poses = lie.w2c_to_c2w(R, t)
        X = X.detach().cpu().numpy()
        info["stage2"]["moving"] = int(moving_s2.sum())

    xyz = np.zeros((N, T, 3), np.float32)  # world metres: float32 is 0.1 um at 100 m, half the traffic
    ok_s2 = s2[~moving_s2]
    xyz[ok_s2] = X[~moving_s2][:, None]
    Dfit = D  # the static tracks' depth target: the prior, or the prior times the optimised points' field
    if cfg.prior_field:
        with tm("prior_field"):
            fields = static_fields(ok_s2, uv, vis, xyz, D, poses, prior.shape[1:], cfg.dc_field_cells,
                                   cfg.dc_field_smooth)
            Dfit = corrected_prior(D, uv, vis, fields)
    thinned = None  # the static tracks' thinned observations (reference_ratios), made by the depth-mover test
    dynamic = labels == DYNAMIC
    steps = LabelSteps(dynamic)  # which step set each label (result.npz's label_step)
    dynamic[s2[moving_s2]] = True
    steps.after("stage2", dynamic)
    fits = StaticFits(uv, Dfit, K, R, t, cfg, device)  # the static fits from here on: poses held
    with tm("classify"):
        core = None
        if cfg.mask_core_px > 0:  # the masks' cores: their dynamic label stands
            core = (labels == DYNAMIC) & (depth_in_mask(tr.tracks, qf, masks) >= cfg.mask_core_px)
        vis = classify_masked(labels, vis, qf, fits, dynamic, xyz, info, p.offsets, core)
        steps.after("classify", dynamic)
    with tm("rebuild_static"):
        vis, once = rebuild_static(labels, s2, ok_s2, moving_s2, vis, qf, D, poses, fits, dynamic, xyz, info, p.offsets)
        steps.after("rebuild_static", dynamic)
    if cfg.depth_mover_log > 0:
        with tm("depth_movers"):
            # static tracks whose fitted depth disagrees with the prior region by region: movers along the
            # epipolar lines that the masks missed and no static point fails to explain (optim.depth_movers)
            cand = np.flatnonzero(~dynamic & (vis.sum(1) >= 2))
            reach = mover_range_px(cfg.depth_mover_range_px, prior, info)
            movers, thinned = depth_mover_test(cand, np.flatnonzero(~dynamic), uv, vis, xyz, D, poses,
                                               prior.shape[1:], replace(cfg, depth_mover_range_px=reach), prior)
            movers = capped_movers(movers, cfg.depth_mover_max_share, info)
            dynamic[cand[movers]] = True
            steps.after("depth_movers", dynamic)
            info["depth_movers"] = int(movers.sum())
            info["depth_mover_range_px"] = reach
            if cfg.verbose:
                blur = info.get("prior_edge_blur_px")
                how = ("as given" if cfg.depth_mover_range_px is not None else "the prior's edge blur: too few edges"
                       if blur is None else f"the prior's edge blur: {blur:.2f} px")
                drop = info.get("depth_movers_dropped")
                why = "" if drop is None else (f" ({drop['flagged']} of the {drop['tested']} tested disagree with the "
                                               f"prior, more than its {drop['cap']:.0%} cap: the prior is wrong there, "
                                               f"none taken for movers)")
                print(f"[depth_movers] {int(movers.sum())} tracks{why}; discrepancies within {reach} px of the prior's "
                      f"extremes ({how})", file=sys.stderr, flush=True)
    if cfg.own_test:
        with tm("rebuild_static"):
            vote_short_tracks(once, tr.queries, vis, D, fits, dynamic, xyz, colours, info, prior.shape[1:],
                              None if cfg.vote_core == "off" else core)
            steps.after("vote", dynamic)
    if cfg.static_outliers and p.offsets:
        with tm("static_outliers"):
            vis = drop_off_point(vis, qf, fits, dynamic, xyz, info)
    if cfg.static_refit_dc > 0 and not cfg.no_depth_consistency:
        with tm("static_refit"):
            # every static point again, poses held, its depth now held to the field-corrected prior: a track
            # seen over a short baseline is placed by the prior, which the field has corrected, more than by
            # its small parallax (after the depth-mover test, which needs the fits that follow the parallax)
            refit = np.flatnonzero(~dynamic & (vis.sum(1) >= 2))
            fits.refit(refit, vis, xyz, cfg.static_refit_dc, REFIT_ITERS)
            thinned = None  # stage 3's field from the refitted points
            info["static_refit"] = int(len(refit))
    rigid = cfg.rigid_movers and not cfg.no_dynamic_opt  # w/o D.O.T: no dynamic optimisation at all
    # stage 3 and the rigid step hold the run's peak: the memory the stages before freed is handed back first
    # (trackingworld.memory.release_freed_memory; before every stage it cost page faults in all of them)
    release_freed_memory()
    with tm("stage3"):
        dyn = np.flatnonzero(dynamic)
        # with the rigid step, the hidden frames are carried beside it (its timing includes them)
        target, carry = place_dynamic(dyn, np.flatnonzero(~dynamic), tr.queries, uv, vis, D, prior, xyz, poses, K,
                                      cfg, dtype, device, log, info, thinned, defer_carry=rigid)
    ahead = None  # the video depth's searches, which read only the 2D tracks, on the second core beside the step
    object_id = np.full(N, -1, np.int32)  # the rigid object that placed each track (result.npz's object_id)
    object_poses = np.zeros((0, T, 4, 4))
    if rigid and target is not None:
        if worker_threads() > 1:
            ahead = SearchAhead(uv, vis, prior.shape[1:])
        release_freed_memory()
        with tm("rigid_movers"):
            object_id[dyn], object_poses = place_rigid(dyn, tr.queries, uv, vis, target, xyz, poses, K, cfg, dtype,
                                                       device, info, (prior.shape[2], prior.shape[1]), carry,
                                                       None if ahead is None else ahead.job())
    target = carry = None  # let go: [Nd,T] and the carrying's [Nd,T,3] (now in xyz)

    with tm("video_depth"):
        # the raw prior here (the ratios scale the raw prior's maps), read at the references by the video depth
        depth, info["video_depth_ahead_frames"] = video_depth(uv, vis, xyz, poses, prior, K, ahead)
    D = None  # not read below: let go ([N,T]; 1.4M tracks x 150 frames, 0.84 GB)
    if cfg.photo_static_grey > 0 and frames is not None:
        with tm("photo_static"):
            # dynamic tracks that are static points dragged off by a mover's flow, found by their colours; last, so
            # that their new points move neither stage 3 nor the video depth (run before stage 3, where they
            # joined the static tracks and left the dynamic ones: default seed 2, dynamic world accuracy 89.0 -> 87.7)
            uv, vis, _ = photo_rescue(uv, vis, qf, Dfit, poses, K, frames, masks, cfg, dynamic, xyz, info, labels,
                                      depth)
            steps.after("photo_static", dynamic)
    if cfg.occluded_static_frames > 0:
        with tm("occluded_static"):
            # dynamic tracks that are static points the tracker followed onto a mover passing in front of them; last
            # too, for the same reason, and it reads the video depth
            # in place where the photometric rescue made uv and vis copies (tr's own arrays are not written)
            uv, vis, _ = occlusion_rescue(uv, vis, qf, depth, poses, K, cfg, dynamic, xyz, info,
                                          in_place=uv is not tr.tracks and vis is not tr.visible)
            steps.after("occluded_static", dynamic)
    if cfg.photo_moving_share > 0 and frames is not None:
        with tm("photo_moving"):
            # short static tracks whose static point does not show its colour where it should be seen: movers the
            # masks missed (labels only, after stage 3: it reads the video depth)
            photo_moving(uv, vis, qf, depth, poses, K, frames, masks, cfg, dynamic, labels, info)
            steps.after("photo_moving", dynamic)
    info["label_steps"] = steps.counts(dynamic)
    object_id, object_poses = kept_objects(object_id, object_poses, dynamic)
    return {"poses_c2w": poses, "xyz": xyz, "is_dynamic": dynamic, "labels": labels, "depth": depth, "K": K,
            "visible": vis, "tracks_2d": uv, "label_step": steps.step, "object_id": object_id,
            "object_poses": object_poses, "info": info}


def kept_objects(object_id: np.ndarray, object_poses: np.ndarray, dynamic: np.ndarray) -> tuple[np.ndarray,
                                                                                                 np.ndarray]:
    """The rigid objects of the final labels: ``object_id [N]`` (-1: none) cleared on the tracks that a later step
    labelled static (the photometric and occlusion rescues place them on static points), the objects left with no
    track dropped and the rest numbered from 0 in their order; ``object_poses [G,T,4,4]`` cut to match."""
    object_id = np.where(dynamic, object_id, -1).astype(np.int32)
    keep = np.flatnonzero(np.bincount(object_id[object_id >= 0], minlength=len(object_poses)) > 0)
    new = np.full(len(object_poses) + 1, -1, np.int32)  # new[-1] = -1 for the tracks in none
    new[keep] = np.arange(len(keep))
    return new[object_id], object_poses[keep]


def check_optim(o: OptimConfig) -> None:
    """InputError (one line, naming the field) for an optimiser setting out of its range: checked by
    :func:`run_trackingworld` and, before any work, by ``pipeline.run.run``."""
    for name, allowed in OPTIM_CHOICES.items():
        if getattr(o, name) not in allowed:
            raise InputError(f"{name}: {getattr(o, name)!r} is not {' or '.join(map(str, allowed))}")
    if not 0 <= o.slip_run <= 1 or o.slip_px <= 0 or o.slip_window < 1:
        raise InputError(f"slip_run {o.slip_run} / slip_px {o.slip_px} / slip_window "
                         f"{o.slip_window}: the run's fraction is from 0 to 1, its bound and window positive")
    if o.vote_colour_sigma < 0 or o.vote_k < 1 or not o.vote_once_gap_px >= 0:
        raise InputError(f"vote_colour_sigma {o.vote_colour_sigma} / vote_k {o.vote_k} / vote_once_gap_px "
                         f"{o.vote_once_gap_px}: the colour weight's width is 0 (off) or more, the voters 1 or "
                         "more, the gap 0 px or more (inf: off)")
    if (o.depth_mover_rounds < 1 or not 0 < o.depth_mover_suspect <= 1
            or (o.depth_mover_range_px is not None and o.depth_mover_range_px < 0) or not o.depth_mover_mad >= 0):
        raise InputError(f"depth_mover_rounds {o.depth_mover_rounds} / depth_mover_suspect {o.depth_mover_suspect} / "
                         f"depth_mover_range_px {o.depth_mover_range_px} / depth_mover_mad {o.depth_mover_mad}: the "
                         "rounds are 1 or more, the suspects' fraction of the threshold over 0 and at most 1, the "
                         "range 0 px or more (None: estimated), the threshold's MADs 0 (off) or more")
    if not (o.depth_mover_bin >= 0 and o.depth_mover_bin_factor >= 0):
        raise InputError(f"depth_mover_bin {o.depth_mover_bin} / depth_mover_bin_factor {o.depth_mover_bin_factor}: "
                         "the depth bins' width is 0 (off) or more (log units), the factor 0 (the bins alone) or more")
    if (o.photo_static_grey < 0 or not 0 <= o.photo_static_frac <= 1 or o.photo_static_frames < 1
            or o.photo_static_near_px < 0 or not 0 <= o.photo_static_range < 1 or not o.photo_static_patch >= 0
            or not o.photo_static_track_px >= 0):
        raise InputError(f"photo_static_grey {o.photo_static_grey} / photo_static_frac {o.photo_static_frac} / "
                         f"photo_static_frames {o.photo_static_frames} / photo_static_near_px "
                         f"{o.photo_static_near_px} / photo_static_range {o.photo_static_range} / "
                         f"photo_static_patch {o.photo_static_patch} / photo_static_track_px "
                         f"{o.photo_static_track_px}: the colour tolerance is 0 (off) or more, the share from 0 to 1, "
                         "the frames 1 or more, the distance 0 or more, the depth range from 0 to below 1, the patch "
                         "tolerance and the track's distance 0 (off) or more")
    if (o.occluded_static_frames < 0 or not 0 <= o.occluded_static_frac <= 1 or not o.occluded_static_px > 0
            or not 0 < o.occluded_static_depth <= 1 or o.occluded_static_in_view < 1):
        raise InputError(f"occluded_static_frames {o.occluded_static_frames} / occluded_static_frac "
                         f"{o.occluded_static_frac} / occluded_static_px {o.occluded_static_px} / "
                         f"occluded_static_depth {o.occluded_static_depth} / occluded_static_in_view "
                         f"{o.occluded_static_in_view}: the frames are 0 (off) or more, the share from 0 to 1, the "
                         "distance over 0 px, the depth ratio over 0 and at most 1, the frames in view 1 or more")
    if not 0 <= o.photo_moving_share <= 1:
        raise InputError(f"photo_moving_share {o.photo_moving_share}: a share from 0 (off) to 1")
    if not 0 <= o.depth_mover_max_share <= 1:
        raise InputError(f"depth_mover_max_share {o.depth_mover_max_share}: a share from 0 (no cap) to 1")
    if not o.mask_core_px >= 0:
        raise InputError(f"mask_core_px {o.mask_core_px}: the depth inside the masks (px) is 0 (off) or more")
    if not o.rigid_split_gap >= 0:
        raise InputError(f"rigid_split_gap {o.rigid_split_gap}: a fraction of the depth, 0 (never) or more")
    if not o.rigid_relay_gap >= 0:
        raise InputError(f"rigid_relay_gap {o.rigid_relay_gap}: a fraction of the depth, 0 (never) or more")
    if o.rigid_key_frames < 0 or o.rigid_key_frames in (1, 2):
        raise InputError(f"rigid_key_frames {o.rigid_key_frames}: 0 (all frames) or 3 or more")
    if o.rigid_second_pass < 0:
        raise InputError(f"rigid_second_pass {o.rigid_second_pass}: the seeds are 0 (one pass) or more")
    if o.dc_edge_sigma_px < 0:
        raise InputError(f"dc_edge_sigma_px {o.dc_edge_sigma_px}: a Gaussian's width (px) is 0 (off) or more")
    if o.dc_target_smooth < 0 or o.dc_field_smooth < 0 or o.dc_field_temporal < 0 or o.dynamic_cell < 0:
        raise InputError(f"dc_target_smooth {o.dc_target_smooth} / dc_field_smooth {o.dc_field_smooth} / "
                         f"dc_field_temporal {o.dc_field_temporal} / dynamic_cell {o.dynamic_cell}: the fields' "
                         "weights and the cell are 0 or more")


# the depth-discrepancy test's cap on an estimated depth prior (OptimConfig.depth_mover_max_share): the eleven
# synthetic runs measured (eight scenes on their given priors, three slow pans on SfM depth) flag 0.2-4.4% of the
# tracks tested, dog.mp4 on its SfM depth 13.6% (stop 89, docs/priors.md)
ESTIMATED_MOVER_SHARE = 0.08


def prior_limits(cfg: OptimConfig, detail: str, refine_focal: bool) -> tuple[OptimConfig, bool, list[str]]:
    """``cfg`` with the steps off that a depth prior of ``detail`` (:attr:`Inputs.depth_detail`) cannot feed, whether
    to refine the focal length (``refine_focal``: as asked), and the names of the steps turned off. A constant
    prior says nothing about depth: the depth-discrepancy test flags every static object that stands out from the
    smooth field (seed 0 with --depth none: 1,366 tracks, static kept 93.4 -> 92.5; SfM without parallax on slow
    synthetic pans: static kept 96.05 / 96.28 against 98.01 / 98.06 without the test and the refit, for +0.9 / +0.1
    of bg-mover recall), the refit would flatten the static points onto that field, and the focal length's
    refinement (``refine_focal`` "auto" only) has no depth to hold it: on the real videos with a constant SfM depth
    (pstudio.mp4's fixed camera, sheep.mp4's pan at 40 and 120 frames) its rounds drifted 5-16% and did not settle,
    and the run kept the starting focal length, the first round's solution, which is what it now solves alone. An
    estimated prior (SfM, a depth model) keeps all three, the test's flags capped at ESTIMATED_MOVER_SHARE of the
    tracks it tests (:func:`optimise`)."""
    off = []
    if detail == "constant":
        if cfg.depth_mover_log > 0:
            cfg = replace(cfg, depth_mover_log=0.0)
            off.append("depth_movers")
        if cfg.static_refit_dc > 0:
            cfg = replace(cfg, static_refit_dc=0.0)
            off.append("static_refit")
        if refine_focal and cfg.refine_focal == "auto":
            refine_focal = False
            off.append("focal_refinement")
    elif detail == "estimated" and cfg.depth_mover_max_share == 0:
        cfg = replace(cfg, depth_mover_max_share=ESTIMATED_MOVER_SHARE)
    return cfg, refine_focal, off


def resolve_vote_core(setting: str, masks_detail: str) -> str:
    """``OptimConfig.vote_core`` for masks from ``masks_detail`` (``Inputs.masks_detail``): "auto" is "on" for masks
    of objects, "off" for the weight-free motion masks, whose cores hold static background; "on" / "off" as given."""
    if setting != "auto":
        return setting
    return "off" if masks_detail == "motion" else "on"


def run_trackingworld(inp: Inputs, tr: TrackResult, cfg: RunConfig, timings: dict | None = None,
                      report: dict | None = None) -> Result:
    """The full method on loaded inputs with their priors and dense tracks; see :func:`optimise`. ``report``
    receives what the optimiser found (stage losses, counts), as written to ``DIR/optim.json``."""
    timings = {} if timings is None else timings
    if inp.depth is None:
        raise InputError(f"{cfg.inputs.input}: no depth prior was resolved")
    check_optim(cfg.optim)
    mode = cfg.optim.refine_focal
    refine = mode == "on" or (mode == "auto" and not intrinsics_given(cfg.inputs.intrinsics))
    optim_cfg, refine, off = prior_limits(cfg.optim, inp.depth_detail, refine)
    # the masks' cores kept through the vote of the short tracks with masks of objects only (OptimConfig.vote_core)
    optim_cfg = replace(optim_cfg, vote_core=resolve_vote_core(optim_cfg.vote_core, inp.masks_detail))
    if off and optim_cfg.verbose:
        print(f"{', '.join(f'[{o}] off' for o in off)}: {inp.depth_note}", file=sys.stderr, flush=True)
    colors = sample_colors(inp.frames, tr.queries)  # the result's, and the vote of the short tracks
    out = optimise(tr, inp.depth, inp.masks, inp.K, optim_cfg, timings, cfg.device, cfg.seed, refine, colors,
                   inp.frames)
    if report is not None:
        report.update(out["info"])
        report["vote_core"] = optim_cfg.vote_core  # as resolved for these masks
        if off:
            report["off_for_the_prior"] = {"steps": off, "why": inp.depth_note}
    K_in = inp.K_in.copy()
    K_in[0, 0] *= out["K"][0, 0] / inp.K[0, 0]
    K_in[1, 1] *= out["K"][1, 1] / inp.K[1, 1]
    W, H = inp.size_in
    qt = tr.queries[:, 0].astype(np.int32)
    depth = resize_stack(out["depth"].astype(np.float32), W, H, cv2.INTER_LINEAR)
    return Result(
        tracks_2d=inp.to_input_pixels(out["tracks_2d"]), visible=out["visible"], tracks_3d=out["xyz"], query_frame=qt,
        is_dynamic=out["is_dynamic"], colors=colors, poses_c2w=out["poses_c2w"],
        intrinsics=K_in, depth=depth, label_step=out["label_step"], object_id=out["object_id"],
        object_poses=out["object_poses"].astype(np.float32),
    )
