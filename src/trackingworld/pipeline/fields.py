"""The depth prior corrected by the optimised static points: per-frame smooth fields of their ratio camera depth /
prior (``optim.ratio_field``), the prior at the tracks read away from its blurred depth edges
(``optim.edge_prior``), stage 3's depth target, and the depth-discrepancy test of the static tracks built on those
fields (``optim.depth_movers``). Array functions over the whole video; :func:`trackingworld.pipeline.world.optimise`
calls them between the stages (conventions: ``uv [N,T,2]`` px, ``vis [N,T]``, depths ``[N,T]`` metres, poses
camera-to-world ``[T,4,4]``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from trackingworld.config import DC_TARGETS, OptimConfig
from trackingworld.geometry import invert_pose, transform
from trackingworld.image import sample_image
from trackingworld.optim.densify import propagate_ratio, thinned_observations
from trackingworld.optim.depth_movers import (
    BilateralWindows,
    blur_tolerant,
    depth_movers_at,
    less_fields,
    log_depth_ratios,
    prior_spread,
)
from trackingworld.optim.edge_prior import edge_blur_px, inner_prior
from trackingworld.optim.ratio_field import fit_log_fields
from trackingworld.optim.rows import Rows
from trackingworld.optim.static_tests import spread_observations
from trackingworld.pipeline.lift import sample_maps

MIN_FIELD_SAMPLES = 50  # static references a frame's depth-correction field needs after the margin
MOVER_RANGE_PX = (1, 4)  # the depth-discrepancy test's estimated range: from the prior's edge blur, within these


@dataclass(frozen=True)
class FieldSettings:
    """Stage 3's depth-target field (``optim.ratio_field``); the defaults are OptimConfig's."""

    cells: tuple[int, int] = OptimConfig.dc_field_cells  # grid cells (gx, gy) over the image
    smooth: float = OptimConfig.dc_target_smooth  # the smoothness penalty's weight
    margin_px: float = OptimConfig.dc_field_margin_px  # static tracks this close to a visible dynamic one left out
    temporal: float = OptimConfig.dc_field_temporal  # coupling of the frames' fields in time
    order: int = OptimConfig.dc_target_order  # the smoothness penalty: 1 first differences, 2 thin plate

    @classmethod
    def stage3(cls, cfg: OptimConfig) -> FieldSettings:
        """The settings ``cfg`` gives stage 3's target field."""
        return cls(cfg.dc_field_cells, cfg.dc_target_smooth, cfg.dc_field_margin_px, cfg.dc_field_temporal,
                   cfg.dc_target_order)


def corrected_prior(D, uv, vis, fields) -> np.ndarray:
    """The prior sampled at the tracks, ``D [N,T]`` metres, times each frame's field at the visible observations
    (``fields``: per frame a ``LogField`` or None: that frame unchanged; :func:`static_fields`): the prior's
    per-frame scale and smooth warp removed where the optimised static points measured them. A copy; hidden
    observations unchanged. uv [N,T,2] px, vis [N,T]. The field is sampled from its image, bilinear between
    pixels: within 3e-4 (relative) of evaluating it at each point, and 20x faster (9.6M points: 0.04 s)."""
    out = D.copy()
    vis_t = np.ascontiguousarray(vis.T)
    for t, f in enumerate(fields):
        w = np.flatnonzero(vis_t[t])
        if f is not None and len(w):
            out[w, t] *= sample_image(np.exp(f.image()), uv[w, t].astype(np.float32))
    return out


def edge_free_prior(prior: np.ndarray, uv: np.ndarray, vis: np.ndarray, idx: np.ndarray, sigma: float,
                    base: np.ndarray, in_place: bool = False) -> np.ndarray:
    """``[N,T]`` metres: at the visible observations of the tracks ``idx`` the prior averaged over those tracks' own
    pixels away from the depth edges (optim.edge_prior.inner_prior), so one side of an edge does not read the
    other's blur; ``base`` [N,T] everywhere else. uv [N,T,2] px, vis [N,T]. The tracks are selected through the
    visibility rather than copied out (120 frames: 1.8 -> 0.7 s), and their samples written into a copy of
    ``base`` (``in_place``: into ``base`` itself) rather than into a new ``[N,T]`` array merged with it."""
    member = np.zeros(len(vis), bool)
    member[idx] = True
    seen = vis & member[:, None]
    return sample_maps(inner_prior(prior, uv, seen, sigma), uv, seen, out=base if in_place else base.copy())


def edge_free_rows(prior: np.ndarray, uv: np.ndarray, vis: np.ndarray, idx: np.ndarray, sigma: float,
                   base: np.ndarray) -> np.ndarray:
    """:func:`edge_free_prior` of the tracks ``idx`` at their rows only: ``[len(idx),T]`` metres, the same numbers as
    its rows ``idx``, without an ``[N,T]`` copy of ``base`` (stage 3 reads the dynamic tracks' rows: 120 frames,
    39k of 257k tracks)."""
    rows, seen = Rows(uv, idx), vis[idx]
    return sample_maps(inner_prior(prior, rows, seen, sigma), rows, seen, out=base[idx])


REFERENCE_CELL_PX = 4.0  # the scale propagation's references: one visible observation per this many px square


def reference_ratios(tracks, uv, vis, xyz, D, poses, cell: float = REFERENCE_CELL_PX):
    """The references of the appendix's scale propagation among ``tracks`` [n] (indices, a set: a cell keeps its
    lowest-index track; None: all), selected through a mask rather than copied out: one visible observation per
    ``cell`` px square of each frame, in frame order. Returns (track [R], frame [R], ratio [R] = camera z of its
    world point / prior depth)."""
    member = None
    if tracks is not None:
        member = np.zeros(len(vis), bool)
        member[tracks] = True
    n, t = thinned_observations(uv, vis, cell, member)
    return n, t, observation_ratios(xyz, poses, n, t, D[n, t])


def observation_ratios(xyz, poses, n, t, depth) -> np.ndarray:
    """``[R]``: camera z of the world points ``xyz[n, t]`` (``xyz [N,T,3]`` metres, poses camera-to-world
    ``[T,4,4]``) over the prior's depth ``depth [R]`` metres at those observations ``(n [R], t [R])``."""
    z = transform(invert_pose(poses)[t], xyz[n, t])[:, 2]
    return z / np.maximum(depth, 1e-6)


def stage3_target(mode: str, xyz, uv, vis, D, dyn, static, poses, K, shape: tuple[int, int] | None = None,
                  field: FieldSettings | None = None, refs=None, prior_dyn: np.ndarray | None = None) -> np.ndarray:
    """Stage 3's depth-consistency target ``[Nd,T]`` metres of the dynamic tracks ``dyn``: the raw prior
    ``D[dyn]`` (``prior``, the paper), times each frame's median ratio z / prior over the visible ``static``
    tracks (``frame``), times that ratio propagated by IDW from the nearest static tracks (``local``), or times a
    robust smooth field of it over the image (``field``: ``optim.ratio_field`` with the settings ``field``, None:
    OptimConfig's defaults; the static tracks within its margin of a visible dynamic one are left out, their prior
    blurred with the object's), which needs the image ``shape`` (h, w)); ``refs``: see :func:`static_fields`.
    ``prior_dyn [Nd,T]``: the dynamic tracks' prior in place of ``D[dyn]`` (``D`` is then read at the static
    tracks only)."""
    Ddyn = D[dyn] if prior_dyn is None else prior_dyn
    target = Ddyn.copy()
    if mode == "prior":
        return target
    if mode not in DC_TARGETS:
        raise ValueError(f"dc_target: {mode!r} is not {' or '.join(DC_TARGETS)}")
    if mode == "field" and shape is None:
        raise ValueError("dc_target 'field' needs the image shape (h, w)")
    fs = field or FieldSettings()
    vis_t = np.ascontiguousarray(vis[dyn].T)
    if mode == "field":
        fields = static_fields(static, uv, vis, xyz, D, poses, shape, fs.cells, fs.smooth, dyn, fs.margin_px, refs,
                               fs.temporal, fs.order)
        for tt, f in enumerate(fields):
            w = np.flatnonzero(vis_t[tt])
            if f is not None and len(w):
                target[w, tt] *= np.exp(f(uv[dyn[w], tt]))
        return target
    n, t, ratio = reference_ratios(static, uv, vis, xyz, D, poses)
    bounds = np.searchsorted(t, np.arange(vis.shape[1] + 1))
    for tt in range(vis.shape[1]):
        ref = slice(bounds[tt], bounds[tt + 1])
        w = np.flatnonzero(vis_t[tt])
        if bounds[tt] == bounds[tt + 1] or not len(w):
            continue
        if mode == "frame":
            target[w, tt] *= np.median(ratio[ref])
        else:
            target[w, tt] *= propagate_ratio(uv[n[ref], tt], D[n[ref], tt], ratio[ref], uv[dyn[w], tt],
                                             Ddyn[w, tt], K, 4)
    return target


def static_fields(static, uv, vis, xyz, D, poses, shape: tuple[int, int], cells: tuple[int, int], smooth: float,
                  near=None, margin: float = 0.0, refs=None, temporal: float = 0.0, order: int = 1) -> list:
    """Per frame, the robust smooth field (``optim.ratio_field.LogField``, log units) of the ratio camera z /
    prior of the ``static`` tracks' thinned observations (None for a frame without any). ``near`` (track
    indices) with ``margin`` px: the static observations this close to one of theirs visible in the frame are
    left out while at least MIN_FIELD_SAMPLES remain. ``refs``: the thinned observations of a superset of
    ``static`` already made (``reference_ratios``), kept where their track is in ``static``. ``temporal`` > 0:
    the frames' fields are fitted together, each one's shape held near its neighbours' in time; ``order``: the
    smoothness penalty's (both ``ratio_field.fit_log_fields``)."""
    if refs is None:
        n, t, ratio = reference_ratios(static, uv, vis, xyz, D, poses)
    else:
        member = np.zeros(vis.shape[0], bool)
        member[static] = True
        n, t, ratio = (a[member[refs[0]]] for a in refs)
    bounds = np.searchsorted(t, np.arange(vis.shape[1] + 1))
    near_t = None if near is None or margin <= 0 else np.ascontiguousarray(vis[near].T)
    out = []
    for tt in range(vis.shape[1]):
        ref = slice(bounds[tt], bounds[tt + 1])
        if bounds[tt] == bounds[tt + 1]:
            out.append(None)
            continue
        ref_uv, ref_ratio = uv[n[ref], tt], ratio[ref]
        w = np.flatnonzero(near_t[tt]) if near_t is not None else []
        if len(w):
            close = cKDTree(uv[near[w], tt]).query(ref_uv, k=1, workers=-1)[0] <= margin
            if (~close).sum() >= MIN_FIELD_SAMPLES:
                ref_uv, ref_ratio = ref_uv[~close], ref_ratio[~close]
        out.append((ref_uv, np.log(np.maximum(ref_ratio, 1e-6))))
    return fit_log_fields(out, shape, cells, smooth, temporal, order=order)


def mover_range_px(setting: int | None, prior: np.ndarray | None, info: dict | None = None) -> int:
    """The depth-discrepancy test's range (px; ``OptimConfig.depth_mover_range_px``): ``setting`` where given,
    else the edge blur of ``prior [T,H,W]`` metres (``optim.edge_prior.edge_blur_px``) rounded to whole pixels,
    within MOVER_RANGE_PX; its lower end where the prior shows too few depth edges to tell, or is not given.
    ``info``: receives the estimate as ``prior_edge_blur_px`` (None: none made) when one is made."""
    if setting is not None:
        return int(setting)
    blur = None if prior is None else edge_blur_px(prior)
    if info is not None:
        info["prior_edge_blur_px"] = blur
    lo, hi = MOVER_RANGE_PX
    return lo if blur is None else int(np.clip(round(blur), lo, hi))


def depth_mover_test(cand, static, uv, vis, xyz, D, poses, shape: tuple[int, int], cfg: OptimConfig, prior=None):
    """The depth-discrepancy test (``optim.depth_movers``) of the tracks ``cand`` (indices) against the fields of
    the ``static`` ones, in ``cfg.depth_mover_rounds`` rounds: each fits the fields again without the movers and
    the suspects of the round before (the tracks that pass the test at ``depth_mover_suspect`` x its threshold).
    A missed mover that fills much of a field cell pulls the field toward its own depth and so hides itself (the
    synthetic ``default`` seed 13: a mover's discrepancy 0.13 before the field, 0.04 after it); left out of the
    field, it shows again. Returns (movers [len(cand)] bool, the static tracks' thinned observations, reused by
    stage 3's target). ``prior [T,H,W]`` (with ``cfg.depth_mover_range_px``, :func:`mover_range_px`): each discrepancy
    is measured to the nearest of the prior at the pixel and its extremes within that many px
    (``optim.depth_movers.blur_tolerant``)."""
    thinned = reference_ratios(static, uv, vis, xyz, D, poses)  # thinned once, filtered by static_fields
    # at most about test_frames of each track's frames, spread over its span (as the classification)
    obs = spread_observations(vis[cand], cfg.test_frames) if cfg.test_frames else vis[cand]
    k, t, e_raw = log_depth_ratios(cand, obs, xyz, D, poses)
    uv_obs = uv[cand[k], t]
    log_d = np.log(np.maximum(D[cand[k], t], 1e-6)) if cfg.depth_mover_bin > 0 else None
    windows, windows_of = None, None  # the bilateral windows (cfg.depth_mover_bin), built once per set of frames
    spread = None  # the prior's range around each observation (its blur at depth edges)
    reach = mover_range_px(cfg.depth_mover_range_px, prior)
    if prior is not None and reach > 0:
        spread = prior_spread(t, uv_obs, prior, reach)
    movers = left_out = np.zeros(len(cand), bool)
    rounds = max(cfg.depth_mover_rounds, 1)
    for r in range(rounds):
        ref = np.setdiff1d(static, cand[movers | left_out], assume_unique=True)
        fields = static_fields(ref, uv, vis, xyz, D, poses, shape, cfg.dc_field_cells, cfg.dc_field_smooth,
                               refs=thinned)
        keep, e = less_fields(uv_obs, t, e_raw, fields)
        if spread is not None:
            e = blur_tolerant(e, spread[0][keep], spread[1][keep])
        if r == 0:  # the threshold: fixed, or raised to a multiple of the first round's spread of e
            threshold = cfg.depth_mover_log
            if cfg.depth_mover_mad > 0 and len(e):
                threshold = max(threshold, cfg.depth_mover_mad * float(np.median(np.abs(e - np.median(e)))))
        thresholds = [threshold]
        if cfg.depth_mover_suspect < 1 and r < rounds - 1:  # the suspects, for the next round's fields
            thresholds.append(threshold * cfg.depth_mover_suspect)
        if log_d is not None and (windows_of is None or not np.array_equal(keep, windows_of)):
            windows = BilateralWindows.build(t[keep], uv_obs[keep], log_d[keep], vis.shape[1], shape,
                                             cfg.depth_mover_window_px, cfg.depth_mover_bin)
            windows_of = keep
        movers, *suspects = depth_movers_at(k[keep], t[keep], uv_obs[keep], e, len(cand), vis.shape[1], shape,
                                            thresholds, cfg.depth_mover_window_px, windows,
                                            cfg.depth_mover_bin_factor)
        if suspects:
            left_out = suspects[0]
    return movers, thinned
