"""The as-static-as-possible tests of tracks with the camera poses held, and what rests on them.

After stage 2 the poses are known: every track outside the bundle adjustment (the other static tracks, the
masks' dynamic and ambiguous ones) is judged by the best static point it has with the poses held (stage 2's
objective with its offsets eliminated, a few Gauss-Newton steps per track). A track whose offsets stay below
epsilon is static (:func:`fits_static`); one that holds a static point around its query frame and then slips
off it is that point, seen in its run only (:func:`rescue_slipped`, ``optim.slip``); a static track's
observations off its point are not of it (:func:`static_outliers`); a track seen once, or in a few frames
only, takes the verdict of its neighbours seen in more (:func:`vote_short`). The fits run in float32 and in chunks
of FIT_CHUNK tracks, on at most about ``test_frames`` of each track's visible frames (:func:`spread_observations`).

Shapes: ``uv [N,T,2]`` px, ``D [N,T]`` metres (the depth target), ``vis [N,T]`` bool, ``qf [N]`` query frames,
``R [T,3,3]``, ``t [T,3]`` world-to-camera (tensors), ``K [3,3]``; ``tracks`` are indices into N.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch
from numba import njit

from trackingworld.config import OptimConfig
from trackingworld.optim import stage2
from trackingworld.optim.densify import propagate_ratio
from trackingworld.optim.rows import Rows
from trackingworld.optim.slip import frames_around, long_runs, run_around

FIT_CHUNK = 1 << 17  # tracks per chunk of the as-static fits and tests (bounds their memory at large videos)


def moving_tracks(R, t, X, p: stage2.BAProblem, cfg: OptimConfig) -> np.ndarray:
    """[N] bool: the tracks of problem ``p`` whose offsets (``cfg.offset_stat`` over their frames) reach epsilon:
    moving background objects, for the optimised static tracks."""
    if not p.offsets:
        return np.zeros(p.n_points, bool)
    return stage2.track_offset_stat(stage2.offset_norms(R, t, X, p), p, cfg.offset_stat) >= cfg.epsilon


def static_points(uv, D, vis, K, R, t, cfg: OptimConfig, dtype, device, iters: int = 6):
    """Each track's best static point with the poses held (stage 2's objective, offsets eliminated; ``iters``
    Gauss-Newton steps). Returns the problem, the poses in ``dtype`` and X [n,3] world (a tensor)."""
    pc = stage2.BAProblem.from_tracks(uv, D, vis, K, cfg, dtype, device)
    R, t = R.to(dtype), t.to(dtype)
    return pc, R, t, stage2.fit_points(R, t, pc, iters)


def fits_static(uv, D, vis, K, R, t, cfg: OptimConfig, dtype, device) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The as-static-as-possible test of tracks (uv [n,T,2] px, prior D [n,T], vis [n,T]) with the poses (R, t
    world-to-camera) held: each track's best static point, and whether its offsets stay below epsilon.
    Returns (still [n] bool, X [n,3] world, largest reprojection residual [n] px of X over the visible frames)."""
    pc, R, t, X = static_points(uv, D, vis, K, R, t, cfg, dtype, device)
    _, r_uv, _ = stage2.residuals(R, t, X, pc)
    worst = torch.zeros(pc.n_points, dtype=r_uv.dtype, device=r_uv.device)
    worst.scatter_reduce_(0, pc.pt, r_uv.norm(dim=-1), reduce="amax")
    return ~moving_tracks(R, t, X, pc, replace(cfg, offset_stat=cfg.test_stat)), X.cpu().numpy(), worst.cpu().numpy()


def chunks(tracks, vis, frames: int):
    """``tracks`` [n] (indices) in chunks of FIT_CHUNK (bounds the memory of the per-observation Gauss-Newton
    blocks at large videos), each with its visible frames spread to at most about ``frames`` (0: all)."""
    for a in range(0, len(tracks), FIT_CHUNK):
        c = tracks[a:a + FIT_CHUNK]
        yield c, spread_observations(vis[c], frames) if frames else vis[c]


def fits_static_chunked(tracks, uv, D, vis, K, R, t, cfg: OptimConfig, device):
    """:func:`fits_static` of ``tracks`` [n] (indices), from at most about ``cfg.test_frames`` of each one's
    visible frames, in float32 and in chunks (:func:`chunks`)."""
    out = [fits_static(Rows(uv, c), Rows(D, c), vc, K, R, t, cfg, torch.float32, device)
           for c, vc in chunks(tracks, vis, cfg.test_frames)]
    return tuple(np.concatenate(x) for x in zip(*out, strict=True))


def slip_runs(tracks, uv, D, vis, qf, px, K, R, t, cfg: OptimConfig, device) -> tuple[np.ndarray, np.ndarray]:
    """The run test of ``optim.slip`` for ``tracks`` [n] (indices): each one's static point fitted to its query
    frame and the ``cfg.slip_window`` visible frames either side (poses R, t world-to-camera held, depth target
    ``D`` [N,T] metres), and the run of its visible frames around the query frame (``qf`` [N]) where that point
    reprojects within ``px`` [n] pixels of the track (``uv`` [N,T,2]). Returns (run [n,T] bool, X [n,3] world
    metres). In float32 and in chunks of FIT_CHUNK tracks."""
    run = np.zeros((len(tracks), vis.shape[1]), bool)
    X = np.zeros((len(tracks), 3), np.float32)
    for a in range(0, len(tracks), FIT_CHUNK):
        c = tracks[a:a + FIT_CHUNK]
        near = frames_around(vis[c], qf[c], cfg.slip_window)
        _, Rf, tf, Xc = static_points(Rows(uv, c), Rows(D, c), near, K, R, t, cfg, torch.float32, device)
        pc = stage2.BAProblem.from_tracks(Rows(uv, c), Rows(D, c), vis[c], K, cfg, torch.float32, device)
        err = np.full(vis[c].shape, np.inf, np.float32)
        err[pc.pt.cpu().numpy(), pc.fr.cpu().numpy()] = stage2.residuals(Rf, tf, Xc, pc)[1].norm(dim=-1).cpu().numpy()
        run[a:a + len(c)] = run_around(vis[c], err > px[a:a + len(c), None], qf[c])
        X[a:a + len(c)] = Xc.cpu().numpy()
    return run, X


def rescue_slipped(tracks, still, X, px, uv, D, vis, qf, K, R, t, cfg: OptimConfig, device):
    """The run test (``optim.slip``, :func:`slip_runs` within ``px`` [n] pixels) of the ``tracks`` [n] (indices)
    whose as-static test failed (``~still`` [n] bool): those with a long run (``cfg.slip_run``) that pass the
    as-static test again over their run (a mover along its epipolar lines can hold a static point's pixels, not
    its depth) become static in place (``still`` set, ``X`` [n,3] world metres their run's point). Returns
    (visibility [N,T]: a copy where runs replaced tracks' visible frames, else ``vis`` itself; how many were
    rescued). ``cfg.slip_run`` 0: off."""
    if cfg.slip_run <= 0 or still.all():
        return vis, 0
    failed = np.flatnonzero(~still)
    run, Xs = slip_runs(tracks[failed], uv, D, vis, qf, px[failed], K, R, t, cfg, device)
    ok = np.flatnonzero(long_runs(run, vis[tracks[failed]], cfg.slip_run))
    if not len(ok):
        return vis, 0
    who = tracks[failed[ok]]
    out = vis.copy()
    out[who] = run[ok]
    holds = fits_static_chunked(who, uv, D, out, K, R, t, cfg, device)[0]
    out[who[~holds]] = vis[who[~holds]]
    ok = ok[holds]
    still[failed[ok]] = True
    X[failed[ok]] = Xs[ok]
    return (out, len(ok)) if len(ok) else (vis, 0)


def static_outliers(tracks, uv, D, vis, xyz, K, R, t, cfg: OptimConfig, device) -> np.ndarray:
    """``[n,T]`` bool: the visible observations of the static ``tracks`` [n] (indices) whose offset from their
    point ``xyz[tracks, 0]`` (world metres) reaches epsilon with the poses (R, t world-to-camera) held: frames
    where the 2D track left its point (slipped onto an occluder, found again off its point). In float32 and in
    chunks of FIT_CHUNK tracks."""
    out = np.zeros((len(tracks), vis.shape[1]), bool)
    for a in range(0, len(tracks), FIT_CHUNK):
        c = tracks[a:a + FIT_CHUNK]
        pc = stage2.BAProblem.from_tracks(Rows(uv, c), Rows(D, c), vis[c], K, cfg, torch.float32, device)
        X = torch.as_tensor(xyz[c, 0], dtype=torch.float32, device=pc.uv.device)
        far = (stage2.offset_norms(R.float(), t.float(), X, pc) >= cfg.epsilon).cpu().numpy()
        rows, cols = np.nonzero(vis[c])  # the problem's observations, track-major, frames ascending
        out[a + rows[far], cols[far]] = True
    return out


def vote_short(once, voters, dynamic, uv, D, vis, qf, K, k: int, colours: np.ndarray | None = None,
               colour_sigma: float = 0.0) -> np.ndarray:
    """``[n]`` bool: dynamic or not, for the tracks ``once`` [n] (indices) seen too briefly to be tested, by the
    inverse-distance-weighted vote of the ``k`` image-nearest ``voters`` (indices of tested tracks) visible in
    that frame, each voting its ``dynamic`` flag ([N] bool), weights 1 / 3D distance of the points lifted with
    the prior ``D`` [N,T] metres (a voter across a depth edge barely counts), times a Gaussian of width
    ``colour_sigma`` grey levels in the RGB difference of the tracks' query-frame ``colours`` [N,3] when both
    are given (densify.propagate_ratio). uv [N,T,2] px, vis [N,T], qf [N] query frames, K [3,3]. A track with no
    voter in its frame keeps its flag."""
    out = dynamic[once].copy()
    voters_t = np.ascontiguousarray(vis[voters].T)
    for q in np.unique(qf[once]):
        sel = np.flatnonzero(qf[once] == q)
        who, d = once[sel], voters[voters_t[q]]
        if len(d):
            out[sel] = propagate_ratio(uv[d, q], D[d, q], dynamic[d].astype(np.float64), uv[who, q], D[who, q], K,
                                       k, ref_colour=None if colours is None else colours[d],
                                       query_colour=None if colours is None else colours[who],
                                       colour_sigma=colour_sigma) >= 0.5
    return out


def spread_observations(vis: np.ndarray, m: int) -> np.ndarray:
    """``[n,T]`` bool: of each track's visible frames ``vis [n,T]``, at most about ``m`` spread evenly over its
    visible span (every ceil(count / m)-th one and the last). Compiled (:func:`_spread_kernel`, one pass a track:
    131k tracks x 120 frames, 0.08-0.10 -> 0.02 s); :func:`spread_observations_numpy` is the reference."""
    return _spread_kernel(np.ascontiguousarray(vis, dtype=bool), int(m))


def spread_observations_numpy(vis: np.ndarray, m: int) -> np.ndarray:
    """:func:`spread_observations` in numpy (the reference of :func:`_spread_kernel`)."""
    count = vis.sum(1)
    step = np.maximum(-(-count // m), 1)
    out = vis.copy()
    long = np.flatnonzero(step > 1)  # the others keep every visible frame
    if len(long):
        v = vis[long]
        rank = np.cumsum(v, axis=1, dtype=np.int32) - 1
        out[long] = v & ((rank % step[long, None].astype(np.int32) == 0) | (rank == count[long, None] - 1))
    return out


@njit(cache=True, nogil=True)
def _spread_kernel(vis, m):
    """:func:`spread_observations`: per track its visible frames counted, then every ``step``-th one by rank and the
    last kept, ``step = ceil(count / m)`` (at least 1)."""
    n, T = vis.shape
    out = np.zeros((n, T), np.bool_)
    for i in range(n):
        count = 0
        for t in range(T):
            if vis[i, t]:
                count += 1
        step = max(-(-count // m), 1)
        rank = 0
        for t in range(T):
            if vis[i, t]:
                out[i, t] = step == 1 or rank % step == 0 or rank == count - 1
                rank += 1
    return out


def fit_static_points(tracks, uv, D, vis, xyz, K, R, t, cfg: OptimConfig, device, iters: int = 6) -> None:
    """``xyz[tracks]`` (in place, every frame) <- each track's static point with the poses held (stage 2's
    objective with ``cfg``'s weights against the prior ``D``), from at most about ``static_fit_frames`` of its
    visible frames, in float32 and in chunks (:func:`chunks`)."""
    for c, vf in chunks(tracks, vis, cfg.static_fit_frames):
        X = static_points(Rows(uv, c), Rows(D, c), vf, K, R, t, cfg, torch.float32, device, iters)[3]
        xyz[c] = X.cpu().numpy()[:, None]
