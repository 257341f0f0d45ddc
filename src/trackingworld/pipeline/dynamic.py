"""Stage 3 on the dynamic tracks (paper Sec. 3.3): their depth target, the control tracks the linear problem is
solved over (``optim.stage3``), the other dynamic observations following their controls, and the hidden frames
carried by their neighbours (``optim.hidden``). Conventions: ``uv [N,T,2]`` px, ``vis [N,T]``, depths ``[N,T]``
metres, world positions ``[N,T,3]`` metres, poses camera-to-world ``[T,4,4]``."""

from __future__ import annotations

import sys
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import torch

from trackingworld.config import OptimConfig
from trackingworld.geometry import camera_depths, focal_length, transform, unproject
from trackingworld.optim import lie, stage3
from trackingworld.optim.densify import cell_cap_mask, cell_representatives, propagate_ratio
from trackingworld.optim.hidden import carry_hidden
from trackingworld.optim.parallel import core_taken, torch_threads, worker_threads
from trackingworld.optim.rigid import RigidSettings, rigid_movers
from trackingworld.optim.rows import Rows
from trackingworld.pipeline.fields import FieldSettings, edge_free_rows, stage3_target
from trackingworld.tracking2d.base import hold_invisible


def place_dynamic(dyn, static, queries, uv, vis, D, prior, xyz, poses, K, cfg: OptimConfig, dtype, device, log,
                  info: dict, thinned=None, defer_carry: bool = False):
    """``xyz[dyn]`` (in place, every frame) <- stage 3's world positions of the dynamic tracks ``dyn`` (indices):
    solved over one control track per (query frame, ``dynamic_cell`` px) cell, the other visible observations
    following their controls' depth correction, the hidden frames carried (or held). ``static`` (indices): the
    static tracks whose field sets the depth target; ``queries [N,3]`` (frame, x, y); ``D`` the prior at the tracks,
    ``prior [T,h,w]`` its maps; ``thinned``: the static tracks' thinned observations when already made
    (:func:`~trackingworld.pipeline.fields.reference_ratios`). Counts go to ``info``. Returns (the depth target of
    the dynamic tracks ``[len(dyn),T]`` metres, None without dynamic tracks; None, or with ``defer_carry`` where
    :func:`can_defer_carry` allows, the carrying of the hidden frames not yet done: a function that returns the
    carried positions ``[len(dyn),T,3]``, for :func:`place_rigid` to run beside the rigid step)."""
    # stage 3's prior of the dynamic tracks [len(dyn),T]: away from their objects' blurred rims (optim.edge_prior)
    edge_free = cfg.dc_edge_sigma_px > 0 and len(dyn)
    D3 = edge_free_rows(prior, uv, vis, dyn, cfg.dc_edge_sigma_px, D) if edge_free else D[dyn]
    target = stage3_target(cfg.dc_target, xyz, uv, vis, D, dyn, static, poses, K, prior.shape[1:],
                           FieldSettings.stage3(cfg), thinned, D3)
    if not len(dyn):
        return None, None
    qf = queries[:, 0].astype(np.int64)
    ctrl = cell_representatives(queries[dyn], cfg.dynamic_cell)
    cd = dyn[ctrl]
    obs = cell_cap_mask(uv[cd], vis[cd], qf[cd], cfg.dynamic_cell, cfg.cell_cap)
    has = obs.any(1)
    ctrl, cd, obs = ctrl[has], cd[has], obs[has]
    xyz[cd] = _dynamic_tracks(uv[cd], obs, target[ctrl], D[cd], qf[cd], poses, K, cfg, dtype, device, log, info)
    # every other visible observation of a dynamic track follows the optimised ones
    follow = vis[dyn].copy()
    follow[ctrl] &= ~obs
    moved = _follow_controls(uv, D, target, dyn, ctrl, obs, follow, xyz, poses, K, cfg.idw_k) if follow.any() \
        else xyz[dyn]
    info["stage3_controls"] = int(len(ctrl))
    info["stage3_observations"] = int(obs.sum())
    # hidden frames: carried by the neighbours' motion, or held (both read the visible frames only)
    if cfg.carry_k > 0:
        # the image motion's weight in the donors' search: the distance two tracks drift apart in
        # carry_motion_frames frames at the dynamic tracks' median depth, per px per frame of difference
        few = slice(None, None, max(1, len(dyn) // 4000))
        z = D3[few][vis[dyn[few]]]
        scale = cfg.carry_motion_frames * float(np.median(z)) / focal_length(K) if z.size else 0.0
        vis_d = vis[dyn]

        def carry():  # moved is this function's own copy: written in place (uv, read by rows, is not written)
            return carry_hidden(moved, vis_d, cfg.carry_k, cfg.carry_reach, uv=uv, rows=dyn, motion_scale=scale,
                                stat=cfg.carry_stat, overwrite=True)

        if defer_carry and worker_threads() > 1 and can_defer_carry(vis_d, qf[dyn]):  # one thread: one at a time
            xyz[dyn] = moved  # the visible frames, which the rigid step reads
            return target, carry
        xyz[dyn] = carry()
    else:
        xyz[dyn] = hold_invisible(moved, vis[dyn])
    return target, None


def can_defer_carry(vis: np.ndarray, qf: np.ndarray) -> bool:
    """Whether the rigid step may run beside the carrying of the hidden frames with the same result: it reads the
    positions of the tracks ``vis [n,T]`` in their visible frames, and at their query frames ``qf [n]``, which the
    carrying leaves as they are where every track is seen in its query frame (a dense tracker's are)."""
    return bool(vis[np.arange(len(qf)), qf].all())


# torch threads of the rigid step on a CPU: its problems are small (a few hundred points, 6 unknowns per frame), and
# on a 16-core machine (H200 host) the step took 22.4 s on 16 threads and 15.9 s on 4 (the demo scene, stop 56)
RIGID_THREADS = 4


def place_rigid(dyn, queries, uv, vis, target, xyz, poses, K, cfg: OptimConfig, dtype, device, info: dict,
                size: tuple[int, int] | None = None, carry=None, beside=None) -> tuple[np.ndarray, np.ndarray]:
    """``xyz[dyn]`` (in place) <- the dynamic tracks that a rigid motion explains placed by it
    (:func:`trackingworld.optim.rigid.rigid_movers`; ``target [len(dyn),T]`` stage 3's depth target; ``size`` the
    image's (W, H), px). Returns the object of each of ``dyn`` ``[len(dyn)]`` (-1: none) and the objects'
    object-to-world poses ``[G,T,4,4]`` (NaN where not solved). ``carry``: :func:`place_dynamic`'s deferred carrying
    of the hidden frames, run on a thread beside the rigid step (which reads the visible frames only,
    :func:`can_defer_carry`), the groups' positions then written into its result: the same numbers as the two one
    after the other, in the time of the longer. ``beside``: more work for that thread once the carrying is done,
    which reads nothing the step writes, counts the core it takes itself (``optim.parallel.core_taken``) and is left
    running when the step ends (the video depth's search ahead, ``pipeline.video_depth.SearchAhead.job``). While the
    thread works, the step and the carrying split their work among the cores left (``worker_threads()`` one less),
    and torch runs the step on one thread fewer throughout."""
    note = (lambda m: print(f"[rigid movers] {m}", file=sys.stderr, flush=True)) if cfg.verbose else None
    settings = RigidSettings(ring_seeds=cfg.rigid_second_pass, split_gap=cfg.rigid_split_gap,
                             relay_gap=cfg.rigid_relay_gap, max_fit_frames=cfg.rigid_key_frames)
    if not cfg.rigid_bridge:
        settings.bridge = None
    pool = ThreadPoolExecutor(1, thread_name_prefix="tw-beside") if carry is not None or beside is not None else None
    try:
        with torch_threads(min(RIGID_THREADS, worker_threads() - (pool is not None))):
            into = None if carry is None else pool.submit(_on_one_core, carry).result
            if beside is not None:
                pool.submit(beside)
            # the dynamic tracks' pixels and positions read in place (Rows), not copied out: 20 bytes an observation
            xyz[dyn], groups, motions, counts = rigid_movers(
                Rows(uv, dyn), vis[dyn], target, Rows(xyz, dyn), poses.astype(np.float64),
                K.astype(np.float64), queries[dyn, 0].astype(np.int64), cfg, settings, note, dtype, device, size, into)
    finally:
        if pool is not None:
            pool.shutdown(wait=False)  # the carrying was waited for (into); ``beside`` may go on
    info.update(counts)
    return groups, motions


def _on_one_core(work):
    """``work()`` with one core counted as taken while it runs (``optim.parallel.core_taken``)."""
    with core_taken():
        return work()


def _follow_controls(uv, D, target, dyn, ctrl, ref_obs, follow, xyz, poses, K, k) -> np.ndarray:
    """World positions ``[Nd,T,3]`` of the dynamic tracks ``dyn``: ``xyz[dyn]`` except at the observations
    ``follow [Nd,T]``, which get their own pixel ray at their target depth (``target [Nd,T]``) times the
    IDW-propagated correction ``z_opt / target`` of the optimised control observations (``dyn[ctrl]`` where
    ``ref_obs``)."""
    T = follow.shape[1]
    cd = dyn[ctrl]
    corr = camera_depths(xyz[cd], poses) / np.maximum(target[ctrl], 1e-6)
    out = xyz[dyn]
    follow_t, ref_t = np.ascontiguousarray(follow.T), np.ascontiguousarray(ref_obs.T)
    for t in range(T):
        w = np.flatnonzero(follow_t[t])
        v = np.flatnonzero(ref_t[t])
        if not len(w):
            continue
        r = propagate_ratio(uv[cd[v], t], D[cd[v], t], corr[v, t], uv[dyn[w], t], D[dyn[w], t], K, k)
        out[w, t] = transform(poses[t], unproject(uv[dyn[w], t], r * target[w, t], K))
    return out


def _dynamic_tracks(uv, vis, target, raw, qf, poses, K, cfg: OptimConfig, dtype, device, log, info) -> np.ndarray:
    """Stage 3 on the dynamic tracks: world positions ``[Nd,T,3]`` where ``vis`` (zero elsewhere: the caller
    fills the hidden frames)."""
    if cfg.no_dynamic_opt:  # "w/o D.O.T": the raw prior lifted with the final poses
        return np.where(vis[..., None], transform(poses[None], unproject(uv, raw, K)), 0.0)
    lambdas = (cfg.lambda_ba, 0.0 if cfg.no_depth_consistency else cfg.lambda_dc, cfg.lambda_arap, cfg.lambda_ts)
    nb = stage3.neighbours(transform(poses[None], unproject(uv, target, K)), vis, qf, cfg.arap_k)
    p = stage3.build_problem(uv, vis, target, poses, K, nb, lambdas, dtype, device, cfg.ts_order)
    d0 = p.target.clone()
    e0 = float(stage3.ray_energy(d0, p))
    if cfg.solver == "adam":
        R, t = lie.c2w_to_w2c(poses, dtype, device)
        Kt = torch.as_tensor(K, dtype=dtype, device=device)
        X = stage3.solve_adam(p, d0, (R, t), Kt, cfg.adam_iters[2], cfg.adam_lr, log)
        e1 = float(stage3.objective(X, p, (R, t), Kt))
    else:
        d = stage3.solve_amg(p, d0) if cfg.stage3_linear == "amg" else stage3.solve_cg(p, d0, log=log)
        X = p.centre + p.ray * d[:, None]
        e1 = float(stage3.ray_energy(d, p))
    info["stage3"] = {"loss_init": e0, "loss": e1, "unknowns": int(p.target.shape[0])}
    out = np.zeros(uv.shape[:2] + (3,))
    kk, tt = np.nonzero(vis)
    out[kk, tt] = X.detach().cpu().numpy()
    return out
