"""Typed configuration of a run. Defaults are the paper's values unless a comment says otherwise."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

DC_TARGETS = ("frame", "prior", "local", "field")  # OptimConfig.dc_target
UPSAMPLERS = ("convex", "convex-mean", "bilinear")  # Track2DConfig.upsampler
STATIC_REBUILDS = ("fit", "idw")  # OptimConfig.static_rebuild
TS_ORDERS = (1, 2)  # OptimConfig.ts_order (optim.stage3.TS_COEFS)
REFINE_FOCAL = ("auto", "on", "off")  # OptimConfig.refine_focal
VOTE_CORE = ("auto", "on", "off")  # OptimConfig.vote_core
CARRY_STATS = ("median", "mean")  # OptimConfig.carry_stat (optim.hidden)
SFM_CONTACTS = ("column", "region")  # InputConfig.sfm_contact (priors.sfm.CONTACT_RULES)
STAGE3_LINEAR = ("cg", "amg")  # OptimConfig.stage3_linear (optim.stage3.solve_cg / solve_amg)
FIELD_ORDERS = (1, 2)  # OptimConfig.dc_target_order (optim.ratio_field: first differences / thin plate)
# the OptimConfig fields that take one of a few values, and those values (checked before a run)
OPTIM_CHOICES = {"refine_focal": REFINE_FOCAL, "static_rebuild": STATIC_REBUILDS, "dc_target": DC_TARGETS,
                 "ts_order": TS_ORDERS, "stage3_linear": STAGE3_LINEAR, "carry_stat": CARRY_STATS,
                 "dc_target_order": FIELD_ORDERS, "vote_core": VOTE_CORE}


def offset_percentile(stat: str) -> int | None:
    """The percentile of an offset statistic ``pNN`` (0-100), None for ``max``; ValueError for anything else."""
    if stat == "max":
        return None
    if stat[:1] == "p" and stat[1:].isdigit() and int(stat[1:]) <= 100:
        return int(stat[1:])
    raise ValueError(f"{stat!r} is not max or a percentile p0-p100 (such as p50)")


@dataclass
class InputConfig:
    input: str = ""
    # depth: .npy/.npz metres | folder of 16-bit PNG mm | a depth model (see priors.depth_models) | sfm | none;
    # None = sfm (weight-free structure from motion)
    depth: str | None = None
    # masks: folder of PNGs (non-zero = dynamic) | .npy bool [T,H,W] | grounded-sam | DETECTOR+SEGMENTER |
    # motion | none; None = motion (weight-free)
    masks: str | None = None
    mask_prompt: str | None = None  # text prompt of a mask model (None: priors.mask_models.DEFAULT_PROMPT)
    intrinsics: str | None = None  # text file (3x3 or fx,fy,cx,cy) | inline "fx,fy,cx,cy" | None/auto
    max_frames: int | None = None
    frame_stride: int = 1
    resize: int | None = None  # long side of the processing resolution (outputs stay at input size)
    # no intrinsics given and no focal length from the depth model: estimate the focal length from the static
    # tracks (priors.focal), falling back to default_fov_deg when the video does not determine it
    self_calibrate: bool = True
    default_fov_deg: float = 60.0
    # the SfM depth's dynamic regions: "column" (each column the ground just below it) | "region" (one value each,
    # before stop 78); priors.sfm.SfMConfig.contact
    sfm_contact: str = "column"
    cache: bool = True  # keep tracks and computed priors in DIR/priors/ for re-runs


@dataclass
class Track2DConfig:
    tracker: str = "flow"  # flow (weight-free) | cotracker3 (learned, see cotracker) | file (see tracks_file)
    cotracker: str = "cotracker3"  # cotracker3 (torch hub) | hub:REPO_OR_DIR[:ENTRY] | checkpoint .pth
    tracks_file: str | None = None  # CoTracker / TAPNet layout .npz, see trackingworld.io.tracks
    grid_stride: int = 4  # s in the paper (Sec. 3.2)
    query_stride: int = 1  # every frame is a query frame (the authors' code: 10)
    first_frame_only: bool = False  # ablation "w/o T.E.F"
    cover_radius: float = 1.0  # r: covered when a visible track lies within r px (0: rounding, as the authors)
    min_component: int = 50  # tau
    dense_mode: str = "upsample"  # upsample (grid + convex upsampler) | direct (every pixel tracked)
    # convex: the weighted local affine fit of the grid neighbours' displacements at the pixel (first-order
    # correct; tracking2d.upsample) | convex-mean: their weighted mean (the paper's convex upsampler) | bilinear
    upsampler: str = "convex"
    flow_preset: str = "fine"
    flow_patch: tuple[int, int] = (4, 2)  # the fine preset's DIS patch side and stride (px); (8, 3) before
    flow_skip_stride: int = 4  # flows this many frames apart bound the drift of chained one-frame steps; 0: off
    flow_drag_px: float = 0.5  # a step leaving its like-moving neighbours' by this + 10% is not observed; 0: off
    # each pairwise flow through a colour-guided weighted median of this radius (px; 0: off): motion boundaries
    # back on the colour edges (tracking2d.flow_tracker.weighted_median). Not in the paper. On the 96 synthetic
    # scenes world accuracy 83.12 -> 83.36, static kept 96.37 -> 96.71, at 1.4x the tracking time at 854x480 and
    # 1.8x at 320x240 (benchmarks/results/scenes_stop95_median*.md against scenes_stop94.md; docs/tracking2d.md)
    flow_median: int = 5
    # a point found again after a gap must look like its query frame's 5x5 patch within this (grey levels, mean
    # absolute difference, patch means removed; tracking2d.flow_tracker). Off (0): static kept and world accuracy
    # up on eight scenes, but missed movers' recall down (docs/tracking2d.md, stop 48)
    flow_refind_patch_diff: float = 0.0


@dataclass
class OptimConfig:
    """World-centric lifting (paper Sec. 3.3 and appendix). Losses are means over their own terms, as in the
    authors' code; pixel errors are in processing-resolution pixels, depths and offsets in metres."""

    solver: str = "lm"  # lm (structured Gauss-Newton / Levenberg-Marquardt, default) | adam (paper, reference)
    # track labelling from the coarse masks
    mask_margin_px: int = 2  # erosion of both mask regions; tracks in the band between are "ambiguous"
    # stage 1: initial poses
    clip_len: int = 5
    inlier_px: float = 1.0  # tau: mean reprojection error (px) under which a static track is an inlier
    max_clip_points: int = 3000  # static tracks per clip used for the clip's poses (random subset)
    # stage 2: dynamic background refinement
    lambda_ba: float = 1.0
    lambda_dc: float = 1.0
    # stage 2's bundle adjustment weighs its depth term by lambda_dc times this (the static fits and stage 3 keep
    # lambda_dc). Lower trusts the parallax over the prior's smooth warp, higher the prior's per-frame scale; ten
    # synthetic scenes at 0.3 / 0.1 / 0.03 gained on some and lost on others, 1 kept (docs/results.md, stop 40).
    # Higher also holds the cameras' scale against the prior's depths, a weak mode that the tracks' noise moves by
    # up to 0.5%: with the true depth as the prior and the true movers' masks, 10 took `default` 50 from 83.7 to
    # 89.8, but with its own inputs from 73.3 to 68.5 (3: 71.7), the warp then placing the points (stop 82,
    # benchmarks/probe_ba_scale.py)
    ba_dc_weight: float = 1.0
    # with this > 0 (radians; not in the paper) each point's depth term in stage 2's bundle adjustment is weighed
    # by p0^2 / (p0^2 + a^2), a the angle its first and last observed camera centres see it under: a point seen
    # from far apart is placed by its parallax rather than by the prior's smooth warp, one seen from nearby by the
    # prior (optim.stage2.parallax_weights). 0: every point alike, the paper
    ba_dc_parallax_rad: float = 0.0
    dc_space: str = "log"  # stage-2 depth residual: log(z / D) (default) | metres (the paper as written)
    lambda_asap: float = 5.0
    epsilon: float = 0.1  # metres (the depth prior's units): a track whose offset norm reaches it is a moving object
    # (not in the paper) stage 2 solved a second time without the observations whose offset reached epsilon
    # (README: nearly every residual sits in the L1 part of the offsets' kernel, so a moving object's
    # observations pull on the poses as hard as the static ones). Ten synthetic scenes: world accuracy 78.99 ->
    # 79.85 on the mean, seed 3 70.5 -> 79.3 (camera ATE 0.16 -> 0.05% of the path), -0.3 at most elsewhere
    stage2_reject: bool = True
    offset_stat: str = "max"  # max (paper) | pNN, a percentile: statistic of ||O(i,t)|| over the visible frames
    # (not in the paper) the statistic of the as-static test of the tracks outside the bundle adjustment (poses
    # held): p75 lets a quarter of a static track's frames leave its point (its 2D track slipped onto an occluder
    # or was found again off its point); those observations are then left out (static_outliers). max: the paper
    test_stat: str = "p75"
    # focal length refined in stage 2 (stage2.refine_focal): auto = when the intrinsics were not given and the depth
    # prior is not constant (pipeline.world.prior_limits) | on | off
    refine_focal: str = "auto"
    # movers the masks missed that slide along the epipolar lines (a static point at another depth explains
    # their pixels): static tracks whose fitted depth disagrees with the prior by this much (log units, after the
    # frame's field, to the prior or its extremes within depth_mover_range_px) in a local majority of a window_px
    # square, in most of their frames, become dynamic (optim.depth_movers; not in the paper; 0: off)
    depth_mover_log: float = 0.03
    depth_mover_window_px: float = 20.0
    # (not in the paper) ... or in a local majority of the observations of the same prior depth in that square:
    # depth bins of depth_mover_bin (log units) and the two beside, at depth_mover_bin_factor x the threshold
    # (0: that majority alone, at the threshold); a mover too small to fill the square (optim.depth_movers.
    # BilateralWindows; stop 91: the stop-74 held-out scenes' bg-mover recall 77.7 -> 80+; 0: off)
    depth_mover_bin: float = 0.1
    depth_mover_bin_factor: float = 2.0
    # (not in the paper) ... and that threshold raised to this many median absolute deviations of the first round's
    # discrepancies where that is more (0: the fixed threshold alone): a prior whose warp the fields follow less
    # well (the `hard` preset's, warped by up to 20%) spreads the discrepancies of static regions wider and the fixed
    # threshold flags them. Their MAD (the last round's): 0.0065-0.0070 on `hard` 0-2, 0.0048-0.0052 on `default`
    # 0 / 4 / 12 / 13, so 6 leaves the `default` scenes' threshold near 0.03 and raises `hard`'s to about 0.04. Off
    # by default: on the four fresh scenes it traded static kept (+0.38) for missed-mover recall (-1.82;
    # docs/lifting.md, item 5)
    depth_mover_mad: float = 0.0
    # the test's rounds: each fits the frames' fields again without the movers found and the suspects (tracks
    # that pass the test at depth_mover_suspect x the threshold), which otherwise pull the field toward
    # themselves where they fill much of a field cell (pipeline.fields.depth_mover_test); suspect 1: movers only
    depth_mover_rounds: int = 3
    depth_mover_suspect: float = 0.5
    # each discrepancy measured to the nearest of the prior at the pixel and the prior's farthest and nearest values
    # within this many px (0: the value at the pixel alone): the prior blurs across depth edges, and a static point
    # beside one reads a mix of both sides, its own side's depth a pixel or two away (optim.depth_movers.
    # blur_tolerant). None: the prior's own edge blur, estimated (optim.edge_prior.edge_blur_px) and rounded, from
    # 1 to 4 px (1 where the prior shows too few depth edges). 1 px was chosen on priors blurred by 1 px (the
    # synthetic `default`, read as 1.05-1.12); on `hard`'s, blurred by 2 (read as 2.05-2.14), 1 px made static points
    # beside depth edges movers: `hard` 0 lost 2.0 points of static kept to the test, two thirds of them within
    # 3 px of an edge (docs/lifting.md, item 5)
    depth_mover_range_px: int | None = None
    # (not in the paper) the test's flags dropped when they are more than this share of the tracks it tests: a prior
    # that disagrees with the static fits over that much of the scene is wrong there, not crossed by movers (0: no
    # cap). Off for a given prior (the synthetic scenes' flag 0.2-4.4% of their candidates, `default` 0's unmasked
    # mover among them); a run on an estimated prior (SfM, a depth model) sets it to
    # pipeline.world.ESTIMATED_MOVER_SHARE: on dog.mp4's SfM depth the test flagged 13.6% of the static tracks, the
    # ground and the fence (stop 89, docs/priors.md)
    depth_mover_max_share: float = 0.0
    # stage 3: dynamic objects
    lambda_arap: float = 100.0
    lambda_ts: float = 10.0
    # temporal smoothness: 1 = the paper's first difference |X_t - X_t-1|^2, a zero-velocity prior that pulls a
    # moving object's depths | 2 = the second difference |X_t+1 - 2 X_t + X_t-1|^2 (default: constant velocity
    # costs nothing; world accuracy +1.3, dynamic +2.3 on the mean of ten synthetic scenes, see optim.stage3)
    ts_order: int = 2
    arap_k: int = 4
    # the lm solver's stage 3 is linear least squares over the ray depths, solved on the run's device by cg =
    # Jacobi-preconditioned CG on the explicit sparse normal equations (default, CPU or GPU) | amg = CG with an
    # algebraic-multigrid preconditioner (pyamg, CPU). cg is faster and closer to the exact minimiser: 0.69 s
    # against 1.59 s on 106,751 unknowns of a 120-frame scene, 7e-8 against 6e-5 relative (README)
    stage3_linear: str = "cg"
    # stage-3 depth target: prior = the raw prior (paper) | frame = the prior times each frame's median z / prior
    # of the static tracks (removes the prior's per-frame scale error) | local = the ratio propagated by IDW from
    # the nearest static tracks (appendix; measured worse: the nearest ones border the object, see README) |
    # field = a robust smooth field of that ratio over the image (optim.ratio_field: the prior's smooth warp;
    # default: world accuracy +1.9 on the mean of 7 synthetic scenes, -1.2 on one, see README)
    dc_target: str = "field"
    # the field: grid cells across and down, smoothness, and the margin (px) around the visible dynamic tracks
    # inside which static tracks are not used (their prior is blurred with the object's)
    dc_field_cells: tuple[int, int] = (8, 6)
    # smoothness: the weight of the node differences per sample per node (optim.ratio_field), of the static
    # side's fields (the static tracks' corrected prior, the depth-mover test) ...
    dc_field_smooth: float = 0.01
    # ... and of stage 3's target field: ten times less stiff (stop 41). The prior's warp curves under a mover more
    # than a stiff field follows from the background around it: on `hard` 0 the target was 3.0% off in depth on
    # the movers' pixels (3.4% per object and frame), 2.2% at 0.001. The static side keeps 0.01: at 0.001 it
    # followed the noise of its samples (ten scenes, world static 87.1 -> 86.5, README). Since stop 52 0.0003 with
    # the thin-plate penalty below (0.001 with first differences before)
    dc_target_smooth: float = 0.0003
    # ... and its penalty: 1 = first differences of the nodes (a membrane: a hole under a mover is filled flat), 2 =
    # the thin-plate energy of second differences (the slopes around the hole continue under it). Not in the paper;
    # 2 since stop 52: twenty-nine synthetic scenes, world accuracy 80.70 -> 80.97 on the mean (23 up, 4 down by
    # 0.09 at most; the 23 not used to choose it +0.27, dynamic +0.44), docs/lifting.md item 6
    dc_target_order: int = 2
    dc_field_margin_px: float = 4.0
    # (not in the paper) the prior the depth terms read, on each side of a depth edge from that side's own tracks:
    # averaged in log over the pixels the static tracks (stages 1-2) / the dynamic tracks (stage 3's target) cover,
    # weighted down where the log prior is steep, with a Gaussian of this many px (optim.edge_prior): a mover's rim
    # reads its inner depth and the background beside it the background's, not the prior's blur of the two. The
    # video depth keeps the raw prior. 0: the prior as sampled. Ten synthetic scenes (README): stage 3's side world
    # accuracy +1.9, dynamic +3.3 on the mean, better on all ten; the static side then +0.5 (static +0.2 to +1.7 on
    # all ten); track and video depth AbsRel lower on all ten (sigma 2: the same accuracy, depth a little worse)
    dc_edge_sigma_px: float = 1.5
    # ... and the weight that holds each frame's field shape near the previous frame's (ratio_field.fit_log_fields;
    # 0: every frame on its own). Not in the paper: the prior's warp drifts slowly, and under a moving object
    # a frame's own static tracks cannot see it while its neighbours in time can (stage 3's target only). 1 since
    # stop 41 (3 before): with the less stiff field the weaker coupling follows the warp's drift better (fifteen
    # scenes: the three `hard` ones +0.1 / +1.7 / +2.8, the `default` ones -0.4 to +1.2; README)
    dc_field_temporal: float = 1.0
    # hidden frames of dynamic tracks: carried by the motion of this many nearest tracks visible both there and in
    # the track's nearest visible frame (optim.hidden; 0: the position at the nearest visible frame is held, as
    # the authors' code does)
    carry_k: int = 8
    # ... those farther than this (metres, and than twice the nearest one's distance) left out: a donor on
    # another object (chosen on ten synthetic scenes; the scale is the depth prior's, metres for metric priors)
    carry_reach: float = 0.3
    # ... and near in image motion too: a difference of 1 px per frame in 2D velocity counts as the distance two
    # tracks at the dynamic tracks' median depth drift apart in this many frames (0: by 3D position alone). Not in
    # the authors' code: objects passing each other lend their motion to each other's hidden tracks otherwise
    carry_motion_frames: float = 8.0
    # ... and their steps combined by their weighted median per coordinate (not in the authors' code, which holds;
    # optim.hidden: a donor on another object does not drag the step along) | mean (the weighted mean, before)
    carry_stat: str = "median"
    # a track inside the sure-dynamic mask region is called static only when its static fit also holds in
    # pixels: largest reprojection residual <= this (px; 0: the offset test alone). Short tracks on a masked mover
    # move less than epsilon over their life and passed the metric test.
    mask_dynamic_px: float = 1.0
    # (not in the paper) ... and a track whose query pixel lies this deep inside its frame's coarse mask or deeper
    # (px, optim.labels.depth_in_mask) is not tested at all: it keeps the masks' dynamic label. A coarse mask is the
    # object dilated by a few pixels, so the static points it covers lie in a band along its border; deeper in is
    # the object, and an object approaching the camera holds a static point's pixels over the few frames a track
    # follows it (`hard` 0 object 9). 0: every masked track is tested (before stop 66). 10 on forty-seven synthetic
    # scenes (stop 66, with the rigid step's final fits): world 3D accuracy 83.782 -> 83.817 (20 up, 25 down by at
    # most 0.67), `hard` 0 73.20 -> 74.43, `default` 23 +1.49; static kept 96.545 -> 96.540 (docs/lifting.md item 3;
    # at stop 64, before those fits, it cost `default` 22 5.4 points). Since stop 93 the vote of the short tracks
    # leaves them alone too (vote_core, with masks of objects): a masked mover seen in vote_short frames or fewer
    # was voted static whole by the background's long tracks (twelve 12-frame videos: dynamic recall 49.0 -> 85.0,
    # world 3D accuracy 70.9 -> 75.5)
    mask_core_px: float = 10.0
    # (not in the paper) a masked / ambiguous track that fails that test (and a static-region track the vote calls
    # moving that fails its own test: ten scenes, static kept 92.23 -> 92.54) is static after all when its 2D track
    # holds a static point from its query frame on and then slips (dragged along by the mover beside it): a
    # point fitted to its slip_window visible frames either side of the query frame reprojects within slip_px
    # (within mask_dynamic_px in the sure-dynamic region) over a run of consecutive visible frames around the
    # query frame that covers at least slip_run of its visible frames (and 3), and the track passes the as-static
    # test over the run alone (an epipolar slider holds a static point's pixels, not its depth). Frames outside it are
    # then not observations of that point (left out, returned not visible). 0: off. Ten synthetic scenes: static
    # kept static +1.1 on the mean (0.5: +0.6; 0.3 with 2 px in the dynamic region too: +1.7 but dynamic recall
    # -3.4 and bg-mover recall down to 79.3), world accuracy unchanged (README)
    slip_run: float = 0.3
    slip_px: float = 2.0
    slip_window: int = 2
    # ... from at most about this many of each track's visible frames, spread over its span with both ends
    # (0: all). 120 frames: 4.95 -> 2.12 s, the same measured accuracy; seed 0: 145 of 145k labels change
    test_frames: int = 16
    # speed-up (appendix): one optimised static track per (query frame, round(xy / cell)) cell
    downsample_cell: int = 8  # 0: optimise every static track
    # of their observations, keep in each (frame, cell) cell those of the cell_cap tracks nearest their own query
    # frame (then the longest) (not in the paper; 0: all): the optimised observations per frame stay bounded
    # as the video grows (densify.cell_cap_mask). The moving-background test still sees every observation.
    cell_cap: int = 1
    idw_k: int = 3
    # the static tracks not optimised: fit = each one's static point with the final poses held (the stage-2
    # objective, offsets eliminated; its own observations, not its neighbours' prior errors) | idw = the
    # appendix's rebuild on its query-frame ray at the IDW-propagated depth (the paper; tracks seen once always)
    static_rebuild: str = "fit"
    # ... from at most about this many of its visible frames, spread over its span (0: all); seed 0: 10 frames
    # gave world static accuracy 66.5 against 67.2 with all, in 1.3 s instead of 3.4; ten scenes (stop 40, docs/
    # results.md): world 81.9 / 82.1 / 82.1 with 10 / 20 / all, optimisation 7.4 / 8.0 / 9.0 s on the mean
    static_fit_frames: int = 10
    # the static tracks' depth target outside stage 2: the prior times the field (optim.ratio_field) of the
    # optimised static points' ratio z / prior in each frame (the prior's per-frame scale and smooth warp), as
    # stage 3's target (not in the paper; False: the raw prior)
    prior_field: bool = True
    # after the depth-mover test every static point is fitted again with the poses held and the depth term's
    # weight raised to this (lambda_dc of the fit, against that target; 0: off, not in the paper): the parallax
    # of a track seen over a short baseline fixes its depth less well than the corrected prior does
    static_refit_dc: float = 100.0
    # the static tracks outside stage 2 that their optimised neighbours' vote calls moving (the appendix) are
    # moving only if their own as-static test fails too, and the tracks seen once (no test possible) take the
    # verdict of the tested tracks nearest them, those inside the masks included (not in the paper; False: the
    # vote alone, mask-dynamic tracks seen once stay dynamic)
    own_test: bool = True
    # ... and that vote, for a track seen once, weighs each voter also by a Gaussian of this width (grey levels) in
    # the RGB difference of their query-frame colours, over its vote_k image-nearest voters (not in the paper; 0:
    # the prior-lifted 3D distance alone over idw_k voters). Beside a mover the prior's blur puts a background
    # pixel near the mover's depth; its colour is the background's. Ten synthetic scenes: static kept static
    # +0.2 to +1.1 on each, dynamic recall +0.36 on the mean, world accuracy within 0.1 (docs/lifting.md, item 4)
    vote_colour_sigma: float = 10.0
    vote_k: int = 16
    # (not in the paper) a track seen in at most this many frames takes that vote too, the voters being the tracks
    # seen in more (1: the tracks seen once alone). A short track cannot fail the as-static test: a far object
    # sliding at 1.5 px a frame moves its point by less than epsilon over 8 frames. On the 'default' scene seed
    # 11, 36% of the tracks on the mover the masks missed were seen in 4-8 frames, and 3% of those were labelled
    # dynamic (all of those seen in 16 or more). The vote turns a short track static -> dynamic only when its own
    # static fit misses a pixel by more than vote_flip_px (0: always): on default seeds 2 and 11 the short static
    # tracks fit their point within 0.16-0.21 px (median), those on the missed movers 1.7-2.1 px (docs/lifting.md,
    # item 4)
    vote_short: int = 10
    # (not in the paper) a track seen once with none of its voters (the tracks seen in more than vote_short frames,
    # one per query frame and 4 px square) within this many pixels takes the vote of every track seen in two frames
    # or more instead, after those are settled (inf: off).
    # At a border the camera leaves, a strip seen once may have only a mover's long tracks near it. Twenty
    # synthetic scenes: static kept 95.83 -> 95.93 (>= 95 on 16 instead of 14), bg-mover recall 92.90 either way,
    # dynamic recall 95.45 -> 95.49 (docs/lifting.md, item 4)
    vote_once_gap_px: float = 8.0
    vote_flip_px: float = 1.0
    # (not in the paper; stop 93) the masks' cores (mask_core_px) are not voted on by that vote either: a masked
    # mover seen in vote_short frames or fewer had only the background's long tracks for voters and was voted static
    # whole (twelve 12-frame videos with the scenes' masks: dynamic recall 49.0 -> 85.0, world 3D accuracy 70.9 ->
    # 75.5). auto: on with masks of objects (a file, a segmentation model), off with the weight-free motion masks,
    # whose cores hold static background the vote takes back (eight scenes with them: static kept 94.57 -> 93.60
    # with the rule on); on | off (docs/lifting.md item 3). The run resolves auto from the masks' source
    # (pipeline.world.resolve_vote_core); optimise() called on arrays reads auto as on
    vote_core: str = "auto"
    # (not in the paper) a dynamic-labelled track is a static point the 2D tracker dragged along with a mover when that
    # point, lifted at its query pixel's depth (0.96-1.04 x the field-corrected prior), shows its query colour (within
    # photo_static_grey grey levels, max over RGB, sigma-1 blur) in at least photo_static_frac of the other frames
    # where it projects outside the masks dilated by 2 px, and there are photo_static_frames of those or more; it
    # is then that point, its 2D track the point's projection, seen where it matched (optim.photo_static; 0: off)
    photo_static_grey: float = 12.0
    photo_static_frac: float = 0.8
    photo_static_frames: int = 3
    # ... the depth scales tried: 1 +- this, in steps of 0.02 (0.1 on twenty scenes: static kept 95.8 -> 95.9, bg-mover
    # recall 92.9 -> 92.7, 2.2x the test's time; docs/results.md, stop 46)
    photo_static_range: float = 0.04
    # ... and, with photo_static_near_px > 0, the tracks of the masks' static region seen that close (px) to the masks
    # in some frame; 0: off (twenty scenes at 4 px: static kept 95.8 -> 96.1 but `default` 10's missed mover, which
    # passes near a masked one, 95.0 -> 79.5 bg-mover recall; docs/results.md, stop 46)
    photo_static_near_px: float = 0.0
    # ... and the frames where the consistent video depth at the projection is less than occluded_static_depth times the
    # point's (a nearer surface hides it) are not tested (False: they are; docs/lifting.md, stop 49)
    photo_static_hidden: bool = True
    # ... and a frame matches only where the 5x5 patch at the projection (mean removed) is within this many grey levels
    # of the query pixel's on the mean too (0: the colour alone; optim.photo_static)
    photo_static_patch: float = 0.0
    # ... and a frame where the track itself is seen more than this many px from the projection matches only where
    # the projection shows the query colour better than the track's own pixel does: a mover with a smooth texture
    # shows it at both (0: the projection alone, as before stop 61; optim.photo_static)
    photo_static_track_px: float = 2.0
    # (not in the paper) after stage 3, groups of dynamic tracks that one rigid motion explains are placed by it: the
    # motion is bundle-adjusted to their 2D tracks with the cameras held, its one free scale to the depth targets of all
    # its frames, so the prior's warp under a mover averages over the video (optim.rigid; False: off, the paper).
    # Twenty-nine synthetic scenes: world 3D accuracy 80.97 -> 82.94, the optimisation 8.1 -> 18.0 s per scene
    # (docs/lifting.md item 6b; the default since stop 56)
    rigid_movers: bool = True
    # (not in the paper) ... and the groups of one object on either side of a gap in its tracks (hidden for a few
    # frames: no track crosses) joined, each group's tracks placed in the other's frames and the gap's by the joined
    # motion (optim.rigid_bridge; False: each group in its own frames, as before stop 62)
    rigid_bridge: bool = True
    # (not in the paper) ... and a second pass of at most this many seeds for the groups, each kept away from the
    # patches the first pass tried: the first pass's failures (12 in a row) are used up on the longest tracks, which
    # lie on objects already grouped and on static background inside the masks, before a shorter-lived mover's tracks
    # seed. Forty-seven synthetic scenes: world 3D accuracy 83.32 -> 83.70, 28 up and 11 down by up to 0.51, the
    # optimisation 14.2 -> 18.9 s per scene (optim.rigid, docs/lifting.md item 6d; 0: one pass, as before stop 63)
    rigid_second_pass: int = 30
    # (not in the paper) ... and a group whose points, in the object's frame, fall apart into pieces more than this
    # times their median depth apart (the others holding 10% of it or more) cut to its largest piece, its motion
    # fitted to that again: one rigid motion (a spin about an axis between them) can explain two objects that pass
    # each other the opposite way over the frames both are seen in, and the group then placed each in the frames
    # only the other was seen in (`hard` 22: objects 2.4 m apart in one group, world 3D accuracy 73.2 -> 75.2; the
    # forty-seven scenes 83.807 -> 83.785, 39 unchanged; optim.rigid, docs/lifting.md item 6f; 0: never)
    rigid_split_gap: float = 0.1
    # (not in the paper) ... and a group whose tracks fall into an earlier and a later set that hardly a track spans
    # and whose points do not come within this fraction of their median depth of each other's is two objects handed
    # over (the first one's tracks lost where the other's begin) and is cut to its larger set (`hard` 22 71.8 ->
    # 74.5, the other 95 synthetic scenes unchanged by it, stop 94; optim.rigid.handed_over, docs/lifting.md item
    # 6f; 0: never)
    rigid_relay_gap: float = 0.05
    # (not in the paper) ... and a group's motion solved in more frames than this bundle-adjusted on this many key
    # frames spread over them, every other frame's pose fitted alone to the points it gave: the dense pose system
    # of the fit grows with the square of its frames (optim.rigid, docs/lifting.md item 6b; 0: all frames, as
    # before stop 90). 48: the `default` (32) and `hard` (48) presets' videos are solved whole, as before
    rigid_key_frames: int = 48
    # (not in the paper) a dynamic-labelled track is its query pixel's static point (lifted at the consistent video
    # depth there) when it lies within occluded_static_px of that point's projection in at least occluded_static_frac
    # of at least occluded_static_in_view frames where the point is in view, and at least occluded_static_frames of its
    # observations are off the point in frames where the video depth there is less than occluded_static_depth times
    # the point's (a nearer surface hides it: the mover the tracker followed). It is then that point, seen where it
    # was on it (optim.occluded_static; 0: off). Twenty synthetic scenes: static kept 95.93 -> 96.52 and bg-mover
    # recall 92.90 -> 92.82 with 3 frames in view; 2 instead of 3 (after photo_static_hidden): 96.67 -> 96.76 and
    # 92.79 -> 92.66 (docs/lifting.md, item 4)
    occluded_static_frames: int = 2
    occluded_static_in_view: int = 2  # ... of at least this many frames where the point is in view
    occluded_static_frac: float = 0.8
    occluded_static_px: float = 2.0
    occluded_static_depth: float = 0.9
    # (not in the paper; 0: off) a static-labelled track of the masks' static region seen in at most vote_short
    # frames, queried more than 2 px from the image's edge, becomes dynamic when its query pixel's static point (the
    # video depth, 0.96-1.04 x) shows its query colour (photo_static_grey) in less than this share of at least 6
    # frames where the point is outside the masks and not hidden: a mover the masks missed has left. Labels only (it
    # runs after stage 3). The default since stop 52; on the twenty synthetic scenes missed-mover recall 92.54 ->
    # 94.08 and static kept 96.90 -> 96.77, on five scenes rendered after the choice 92.41 -> 94.05 and 97.08 -> 96.93
    # (docs/lifting.md, item 4)
    photo_moving_share: float = 0.2
    static_outliers: bool = True
    dynamic_cell: int = 4  # stage-3 control tracks: one per (query frame, round(xy / cell)); 0: every dynamic
    # track (the paper). The others follow their control tracks' depth correction by IDW, like static ones.
    # cell_cap applies to the control tracks' observations too (per frame and dynamic_cell cell).
    # solvers
    lm_iters: int = 15
    # stop when the relative decrease of the loss falls below this (the focal refinement uses at most 1e-6);
    # 1e-6 ran 15 iterations instead of 10 at 120 frames and changed no measured error (README, scaling)
    lm_tol: float = 1e-4
    adam_iters: tuple[int, int, int] = (1000, 2000, 1000)  # stages 1, 2, 3 (the paper's schedule)
    adam_lr: float = 1e-3
    dtype: str = "float64"
    # ablations of the paper's Table (all False = full method)
    no_pose_init: bool = False
    no_inliers: bool = False
    no_offsets: bool = False
    no_depth_consistency: bool = False
    no_dynamic_opt: bool = False  # "w/o D.O.T": no stage 3 and no rigid-mover step (the raw prior lifted)
    verbose: bool = True


@dataclass
class RunConfig:
    method: str = "trackingworld"
    device: str = "cpu"
    seed: int = 0
    inputs: InputConfig = field(default_factory=InputConfig)
    track2d: Track2DConfig = field(default_factory=Track2DConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)

    def to_dict(self) -> dict:
        return asdict(self)
