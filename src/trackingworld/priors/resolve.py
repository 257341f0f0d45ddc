"""Choosing and computing a run's priors: depth, dynamic masks, intrinsics.

Each prior comes from a file, a model, or the video itself (weight-free, the default):

=============  ==========================================  ==========================================
prior          given                                       default (``None``)
=============  ==========================================  ==========================================
depth          FILE | model name / ``hf:ID`` / folder      ``sfm``: structure from motion on the tracks
               | ``sfm`` | ``none`` (constant 1)
masks          DIR | FILE | ``grounded-sam`` /              ``motion``: motion the camera cannot explain
               ``DETECTOR+SEGMENTER`` | ``motion`` | none
intrinsics     FILE | ``fx,fy,cx,cy``                      ``auto``: the depth model's focal length when it
                                                           has one, else self-calibrated from the static
                                                           tracks (epipolar), else a 60 deg horizontal
                                                           field of view
=============  ==========================================  ==========================================

Computed priors are cached in ``DIR/priors/`` with a key of everything they depend on.
"""

from __future__ import annotations

import hashlib
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from trackingworld import __version__
from trackingworld.config import RunConfig
from trackingworld.errors import InputError
from trackingworld.geometry import intrinsics_matrix, scale_intrinsics
from trackingworld.io.cache import cached, content_identity, file_identity
from trackingworld.io.priors import fill_invalid_depth
from trackingworld.loaded_models import loaded
from trackingworld.pipeline.inputs import Inputs
from trackingworld.pipeline.lift import sample_maps
from trackingworld.priors.align import disparity_to_depth
from trackingworld.priors.focal import estimate_focal
from trackingworld.priors.mask_models import DEFAULT_PROMPT
from trackingworld.priors.motion_masks import MotionMaskConfig, motion_masks
from trackingworld.priors.sfm import SfMConfig, sfm_depth
from trackingworld.priors.sources import depth_source, intrinsics_given, mask_source
from trackingworld.tracking2d.base import TrackResult


@dataclass
class PriorInfo:
    depth: str = ""
    masks: str = ""
    intrinsics: str = ""
    messages: list[str] = field(default_factory=list)
    sfm: dict = field(default_factory=dict)
    focal: dict = field(default_factory=dict)


def depth_detail(source: str, sfm: dict | None) -> tuple[str, str]:
    """(detail, why) of a depth prior from ``source`` (:func:`~trackingworld.priors.sources.depth_source`: file,
    model, sfm, none), ``sfm`` the SfM's figures (``PriorInfo.sfm``) where its depth is the prior: "given" (a file);
    "estimated" (SfM, a depth model); "constant", no depth (``--depth none``, or SfM that found no parallax). The
    lifting turns off, or caps, what such a prior cannot feed (:func:`trackingworld.pipeline.world.prior_limits`)."""
    if source == "none":
        return "constant", "--depth none gives no depth to compare with"
    if source == "file":
        return "given", ""
    if source == "sfm" and not (sfm or {}).get("ok"):
        return "constant", "the SfM depth is constant (no parallax to triangulate from)"
    return "estimated", ""


def _say(info: PriorInfo, msg: str, verbose: bool) -> None:
    info.messages.append(msg)
    if verbose:
        print(f"[priors] {msg}", file=sys.stderr, flush=True)


def _settings(cfg) -> dict:
    """A prior's config as a cache key (its verbosity does not change the result)."""
    return {**cfg.__dict__, "verbose": None}


def static_tracks(tr: TrackResult, masks: np.ndarray) -> np.ndarray:
    """[N] bool: tracks off the dynamic masks in most of their visible frames."""
    m = sample_maps(masks.astype(np.float32), tr.tracks)
    n = np.maximum(tr.visible.sum(1), 1)
    return (np.where(tr.visible, m, 0).sum(1) / n) < 0.5


def tracks_key(cfg: RunConfig, w: int, h: int) -> dict:
    """What the dense tracks of a run depend on (the cache key of the tracks and of every prior made from them)."""
    ic = cfg.inputs
    return {"version": __version__, "input": content_identity(ic.input), "max_frames": ic.max_frames,
            "stride": ic.frame_stride, "size": [w, h], "track2d": cfg.track2d.__dict__,
            "tracks_file": content_identity(cfg.track2d.tracks_file)}


def _intrinsics(inp: Inputs, tr: TrackResult, ic, K: np.ndarray, K_given: bool, pred, masks: np.ndarray,
                info: PriorInfo, seed: int, verbose: bool) -> np.ndarray:
    """K at the processing resolution: given; else a depth model's focal length; else self-calibrated from the
    static tracks; else the assumed field of view."""
    T, h, w = inp.frames.shape[:3]
    if K_given:
        info.intrinsics = f"given ({ic.intrinsics})"
        return K
    if pred is not None and pred.focal_px:
        info.intrinsics = f"focal length {pred.focal_px:.1f} px from {ic.depth}"
        K = intrinsics_matrix(pred.focal_px, pred.focal_px, (w - 1) / 2, (h - 1) / 2)
    elif ic.self_calibrate:
        f, finfo = estimate_focal(tr, static_tracks(tr, masks), (w, h), seed=seed)
        info.focal = finfo
        if f is not None:
            K = intrinsics_matrix(f, f, (w - 1) / 2, (h - 1) / 2)
            info.intrinsics = (f"self-calibrated from the video: focal {f:.1f} px at {w}x{h} "
                               f"({finfo['fov_deg']:.1f} deg horizontal field of view, {finfo['pairs']} frame pairs)")
        else:
            info.intrinsics = (f"assumed: {ic.default_fov_deg:.0f} deg horizontal field of view "
                               f"(self-calibration found nothing: {finfo['reason']})")
    else:
        info.intrinsics = f"assumed: {ic.default_fov_deg:.0f} deg horizontal field of view"
    _say(info, f"intrinsics {info.intrinsics}", verbose)
    return K


def resolve_priors(inp: Inputs, tr: TrackResult, cfg: RunConfig, cache_dir: Path | None,
                   verbose: bool = True, key: dict | None = None) -> tuple[Inputs, PriorInfo]:
    """Fill in the priors ``inp`` lacks (depth, masks, intrinsics) at the processing resolution; ``key``: the
    run's :func:`tracks_key` when already made (None: made here)."""
    ic = cfg.inputs
    T, h, w = inp.frames.shape[:3]
    info = PriorInfo()
    base_key = {**(tracks_key(cfg, w, h) if key is None else key), "seed": cfg.seed}

    def path(name: str) -> Path | None:
        return None if cache_dir is None else cache_dir / f"{name}.npz"

    K, K_given = inp.K, intrinsics_given(ic.intrinsics)

    # depth models run first: Depth Pro and UniDepth also give the focal length
    dsrc, pred = depth_source(ic.depth), None
    if dsrc == "model":
        from trackingworld.priors.depth_models import DepthPrediction, load_depth_model

        def run_model():
            p = loaded("depth", ic.depth, cfg.device, load_depth_model).predict(inp.frames, verbose)
            return {"values": p.values, "kind": np.array(p.kind), "focal": np.array(p.focal_px or np.nan)}

        key = {**base_key, "model": file_identity(ic.depth)}  # a local folder by its files, a hub id by name
        z = cached(path("depth_model"), key, run_model, "depth model", verbose)
        pred = DepthPrediction(z["values"], str(z["kind"]), None if np.isnan(z["focal"]) else float(z["focal"]))
    msrc = mask_source(ic.masks)
    masks = inp.masks
    if msrc == "model":
        from trackingworld.priors.mask_models import load_mask_model

        prompt = ic.mask_prompt or DEFAULT_PROMPT

        def run_mask_model():
            model = loaded("masks", ic.masks, cfg.device, load_mask_model)
            return {"masks": model.predict(inp.frames, prompt, verbose)}

        z = cached(path("masks_model"), {**base_key, "model": ic.masks, "prompt": prompt}, run_mask_model,
                   "mask model", verbose)
        masks = z["masks"].astype(bool)
        info.masks = f"{ic.masks} (prompt {prompt!r})"
    elif msrc == "motion":
        mcfg = MotionMaskConfig(verbose=verbose)
        z = cached(path("masks_motion"), {**base_key, "cfg": _settings(mcfg)},
                   lambda: {"masks": motion_masks(tr, (T, h, w), mcfg, cfg.seed)[0]},
                   "motion masks", verbose)
        masks = z["masks"].astype(bool)
        info.masks = "motion (weight-free)"
    elif msrc == "none":
        masks = np.zeros((T, h, w), bool)
        info.masks = "none"
    else:
        info.masks = f"file {ic.masks}"

    K = _intrinsics(inp, tr, ic, K, K_given, pred, masks, info, cfg.seed, verbose)

    depth = inp.depth
    need_sfm = dsrc == "sfm" or (pred is not None and pred.kind == "disparity")
    sfm = None
    if need_sfm:
        scfg = SfMConfig(verbose=verbose, contact=ic.sfm_contact)
        key = {**base_key, "masks": hashlib.sha1(np.packbits(masks)).hexdigest(), "K": K.round(6).tolist(),
               "cfg": _settings(scfg)}

        def run_sfm():
            r = sfm_depth(tr, static_tracks(tr, masks), K, masks, scfg)
            return {"depth": r.depth, "ok": np.array(r.ok), "message": np.array(r.message),
                    "parallax_px": np.array(r.info.get("parallax_px", 0.0)),
                    "motion_px": np.array(r.info.get("motion_px", np.nan)),
                    "epipolar_px": np.array(r.info.get("epipolar_px", np.nan))}

        sfm = cached(path("depth_sfm"), key, run_sfm, "structure from motion", verbose)
        # the starting pair's residual parallax, its static tracks' motion and the essential matrix's median Sampson
        # error there, px (None where SfM stopped before them, priors.sfm.reconstruct, or a cache file lacks them)
        found = {k: float(sfm.get(k, np.nan)) for k in ("parallax_px", "motion_px", "epipolar_px")}
        info.sfm = {"ok": bool(sfm["ok"]), **{k: v if np.isfinite(v) else None for k, v in found.items()}}
        _say(info, str(sfm["message"]), verbose)
    if dsrc == "sfm":
        depth = sfm["depth"]
        info.depth = "structure from motion (weight-free, arbitrary scale)"
    elif dsrc == "none":
        depth = np.ones((T, h, w), np.float32)
        info.depth = "none (constant 1)"
    elif dsrc == "model":
        if pred.kind == "metric":
            depth = pred.values
            info.depth = f"{ic.depth} (metric)"
        else:
            ok = bool(sfm["ok"])
            depth = disparity_to_depth(pred.values, sfm["depth"] if ok else None, ~masks if ok else None)
            info.depth = (f"{ic.depth} (relative, scale and shift fitted per frame to structure from motion)" if ok
                          else f"{ic.depth} (relative, shift assumed 0, arbitrary scale: no parallax)")
        depth = fill_invalid_depth(depth)
    else:
        info.depth = f"file {ic.depth}"
    if not np.isfinite(depth).any():
        raise InputError(f"{ic.depth}: no usable depth")
    W, H = inp.size_in
    K_in = inp.K_in if K_given else scale_intrinsics(K, W / w, H / h)
    detail, why = depth_detail(dsrc, info.sfm if dsrc == "sfm" else None)
    return replace(inp, depth=depth.astype(np.float32), masks=masks, K=K, K_in=K_in, depth_detail=detail,
                   depth_note=why, masks_detail=msrc if msrc in ("motion", "none") else "objects"), info
