"""Rigid movers: one rigid motion per group of dynamic tracks, fitted to their 2D tracks (not in the paper).

Stage 3's depths of a moving object are the depth prior corrected by a field fitted to the static background
around it, and a monocular prior's warp under an object drifts as the object crosses the image: the object comes
out a few percent too near in some frames and too far in others, a scale error the neighbour-wise ARAP term
cannot see (it compares a few centimetres between neighbours). A rigid object seen by a camera of known poses is
determined by its 2D tracks up to one scale for the whole video (every frame's points may be scaled about that
frame's camera centre by the same factor), so fitting one rigid motion to a group's 2D tracks and its scale to
the depth targets of all its frames averages the prior's warp over the whole video. The fit is stage 2's
bundle adjustment (:func:`trackingworld.optim.stage2.solve_lm`: Huber reprojection and log-depth terms, Schur
complement) with the object as the scene and camera-from-object poses as its unknowns; its frame is the camera's
frame in the group's reference frame, which stays fixed.

Groups are found one at a time (:func:`rigid_movers`): the longest remaining track and the ``seed_tracks`` tracks
nearest it in its query frame (at depths within ``depth_tol``) give a first motion; the group grows from that patch
over image neighbours (:func:`neighbour_pairs`) through the tracks the motion explains: a median reprojection error
of ``max_px`` or less and an 80th percentile of ``max_px80`` or less over 3 or more frames, and a depth on the motion
within ``depth_tol`` of the target's. The motion is fitted again to the group and the group grown again
(``rounds``, short fits), then with the full fit, again while the group keeps changing (``final_rounds``), so that
the motion that places a group is the one fitted to it; a group of fewer than ``min_tracks`` tracks is dropped. The
search ends after ``max_failed`` seeds in a row gave no group; a second search (``ring_seeds``) then seeds only
``seed_ring`` steps of the neighbour graph away from every patch and group the first one tried. Tracks of a
non-rigid object, of the background, or that jump from one object to another are not explained and keep stage 3's
positions. A track in a group takes the motion's positions in every frame the motion is solved in, its hidden frames
too. A group whose points fall apart, in the object's frame, into pieces farther apart than ``split_gap`` times
their depth is two objects that one motion explained where both were seen (:func:`pieces`): it is cut to its
largest piece, grown again from that; a group whose tracks fall into an earlier and a later set that hardly a
track spans, their points apart in the object's frame, is two objects handed over where one was lost as the other
came into view (:func:`handed_over`), and is cut to its larger set likewise. The groups of one object on either side
of a gap no track crosses are then joined (:mod:`trackingworld.optim.rigid_bridge`).

Conventions: ``uv [N,T,2]`` px, ``vis [N,T]``, depths ``[N,T]`` metres, world positions ``[N,T,3]`` metres,
poses camera-to-world ``[T,4,4]`` (OpenCV axes).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from trackingworld.geometry import (
    camera_depths,
    depth_along,
    invert_pose,
    pose_from_rt,
    project,
    rigid_transform,
    transform,
)
from trackingworld.optim import lie, point_fit, stage2
from trackingworld.optim.rigid_bridge import BridgeSettings, RigidObject, bridge
from trackingworld.optim.rows import Rows


@dataclass
class RigidSettings:
    """How groups are formed and fitted (:func:`rigid_movers`)."""

    neighbours: int = 6  # nearest tracks each track is tested against in its query frame
    neighbour_px: float = 3.0  # within this image distance there
    depth_tol: float = 0.1  # largest relative depth difference of two joined tracks there
    min_tracks: int = 200  # smallest group kept
    seed_tracks: int = 200  # tracks in a seed patch
    max_seeds: int = 30  # most seed patches tried
    max_failed: int = 12  # stop after this many seeds in a row gave no group
    # a second pass of at most ring_seeds seeds (0: none), ending after ring_failed in a row gave no group, whose
    # seeds keep seed_ring steps of the neighbour graph (:func:`neighbour_pairs`) away from every seed patch and
    # group tried before (they may still join a group): the longest tracks lie on the objects already tried, and
    # seeds drawn there again and again used up max_failed before the shorter-lived movers had one. Forty-seven
    # scenes 83.32 -> 83.70 (`hard` 1 / 2 / 13 +3.2 / +2.4 / +2.6), the groups of the first pass unchanged; as one
    # pass with the ring (stop 62) the 120-frame video of bench_scaling.py lost 1.8 points, with a second pass
    # nothing (docs/lifting.md item 6d)
    ring_seeds: int = 30
    ring_failed: int = 18
    seed_ring: int = 3
    min_seen: int = 6  # frames a track must be seen in to join a group
    rounds: int = 8  # most fits of a group's motion, each to the tracks the one before explained ...
    # ... until the group changes by no more than this fraction of its tracks. The rounds' groups keep changing by
    # 2-4% from one to the next once grown (each round's fit draws its own tracks); 0.02 ran them to the last round.
    # With 0.04, thirty-five scenes 83.14 -> 83.21 (14 up, 13 down, `hard` 3 +2.23, `default` 22 -0.25) and the
    # 120-frame video's step 20.8 -> 13.5 s (docs/lifting.md 6b, stop 60)
    settle: float = 0.04
    # full fits again, each to the group the one before grew, while it changes by more than ``settle``: the rounds'
    # fits are short and end on a group the full fit then grows by up to 4x (`default` 22: 556 -> 2,125 tracks),
    # and its motion, fitted to a corner of the object, placed the rest 5% too far (docs/lifting.md item 6e)
    final_rounds: int = 3
    # tracks in the bundle adjustment (the rest are fitted to its poses), drawn with a chance in proportion to the
    # frames each is seen in: the long tracks tie the motion's far-apart frames together. A uniform draw left an
    # object whose tracks were lost and started again halfway (the 120-frame video of bench_scaling.py) with its
    # halves' relative motion off: the tracks of one half placed in the other's frames 20 cm off (docs/lifting.md 6b)
    max_fit: int = 800
    # most frames in that bundle adjustment (0: all): a motion solved in more frames is fitted in this many key
    # frames spread evenly over them (its reference frame one of them), its other frames' poses then fitted alone to
    # the points it gave (:func:`~trackingworld.optim.stage2.fit_poses`, each frame its own 6 unknowns). The reduced
    # pose system of the bundle adjustment is dense, (6F)^2 for F frames, and its tracks on a long video are seen in
    # most of them: its cost grew with the square of the frames (the 120-frame video of bench_scaling.py: the step
    # 5.7x its 30-frame windows'). 48: no video of the `default` (32) and `hard` (48) presets changes
    max_fit_frames: int = 48
    rng_seed: int = 0  # the draws' random seed
    # each track's key fixed once for every draw (:func:`_draw`): far steadier under small changes of the input, but
    # forty-seven scenes 83.817 -> 83.805 and `hard` 0 74.43 -> 73.91 (stop 67, docs/lifting.md item 6b); off (False):
    # a fresh draw from ``rng_seed``'s generator each fit
    keyed_draw: bool = False
    max_px: float = 0.6  # a track's largest median reprojection error under the rigid motion
    max_px80: float = 1.5  # ... and 80th percentile of it
    iters: int = 30  # Levenberg-Marquardt iterations of a group's final fit
    round_iters: int = 6  # ... and of the fits while it grows
    dc_weight: float = 1.0  # the depth term's weight in the rigid fit, times the optimiser's lambda_dc
    # the group's scale then set so that its median depth ratio to the targets is 1 (off: the fit's own scale; on,
    # twenty-nine scenes 82.94 -> 83.07, 19 up and 9 down by up to 0.86: docs/lifting.md item 6b, stop 56)
    median_scale: bool = False
    # groups of one object on either side of a gap no track crosses, joined (optim.rigid_bridge; None: not joined)
    bridge: BridgeSettings | None = field(default_factory=BridgeSettings)
    # a group whose points, in the object's frame, fall apart into pieces more than split_gap x their median depth
    # apart, the others holding split_share of it or more, is cut to its largest piece (0: never)
    split_gap: float = 0.1
    split_share: float = 0.1
    # a group whose tracks fall into an earlier and a later set, fewer than relay_share of the smaller set's tracks
    # explained (within max_px80) in 3 or more frames on both sides of some frame, each set of min_tracks or more,
    # whose points do not meet in the object's frame (fewer than relay_touch of either set's points within
    # relay_gap x the group's median depth of the other's) is two objects handed over: the tracks of one lost where
    # the other's begin, the motion following the first before and the second after, each then placed by the
    # other's motion where hidden. It is cut to its larger set (0: never). The later tracks of one object picked up
    # where its earlier ones were lost lie on the same surface (docs/lifting.md item 6f)
    relay_gap: float = 0.05
    relay_share: float = 0.1
    relay_touch: float = 0.1


def neighbour_pairs(uv: np.ndarray, vis: np.ndarray, z, qf: np.ndarray, s: RigidSettings) -> np.ndarray:
    """Pairs ``[P,2]`` of tracks: each track with its ``neighbours`` nearest tracks seen in its query frame
    ``qf [N]``, within ``neighbour_px`` there and at depths ``z [N,T]`` (an array or :class:`CameraDepths`) within
    ``depth_tol``."""
    pairs = []
    for t in range(vis.shape[1]):
        q = np.flatnonzero(qf == t)
        cand = np.flatnonzero(vis[:, t])
        if not len(q) or len(cand) < 2:
            continue
        k = min(s.neighbours + 1, len(cand))
        d, j = cKDTree(uv[cand, t]).query(uv[q, t], k=k, distance_upper_bound=s.neighbour_px)
        d, j = d.reshape(len(q), k), j.reshape(len(q), k)
        ok = np.isfinite(d)
        a = np.repeat(q, k).reshape(len(q), k)[ok]
        b = cand[j[ok]]
        keep = (a != b) & (_log_ratio(z[a, t], z[b, t]) <= s.depth_tol)
        pairs.append(np.stack([a[keep], b[keep]], 1))
    return np.concatenate(pairs) if pairs else np.zeros((0, 2), np.int64)


def _pixel_rows(uv, idx):
    """(the array that holds the pixels ``uv`` (an array or :class:`Rows`), the rows of it ``idx`` takes)."""
    return (uv.array, uv.of(idx)) if isinstance(uv, Rows) else (uv, idx)


class CameraDepths:
    """The camera z ``[...]`` (metres) of world positions ``xyz [N,T,3]`` in the frames of camera-to-world ``poses
    [T,4,4]``, computed where indexed (``z[rows, frames]``, each an index or an array) rather than held: an ``[N,T]``
    float64 array is 8 bytes an observation, and the step reads a few of them. The numbers are those of
    :func:`~trackingworld.geometry.camera_depths` (both :func:`~trackingworld.geometry.depth_along`)."""

    def __init__(self, xyz: np.ndarray, poses: np.ndarray):
        self.xyz, self.row = xyz, invert_pose(poses)[:, 2]  # [T,4] the world-to-camera row of z

    def __getitem__(self, key) -> np.ndarray:
        rows, frames = key
        return depth_along(self.xyz[rows, frames], self.row[frames])


def _ring(adj, idx: np.ndarray, hops: int) -> np.ndarray:
    """The tracks ``idx`` and those within ``hops`` steps of them in the symmetric adjacency ``adj`` (CSR)."""
    for _ in range(hops):
        idx = np.union1d(idx, adj[idx].indices)
    return idx


def _log_ratio(a, b) -> np.ndarray:
    """``|log(a / b)|`` of depths (metres), each floored at 1 um."""
    return np.abs(np.log(np.maximum(a, 1e-6) / np.maximum(b, 1e-6)))


def _to_median_scale(pos: np.ndarray, vis: np.ndarray, target: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """A group's world positions ``pos [n,T,3]`` (NaN where unsolved) scaled about each frame's camera centre by
    the one factor that makes the median of ``target / depth`` over the group's seen observations 1. Every
    frame's points scaled by one factor about its camera is the scale a monocular rigid fit leaves free: the
    2D tracks are unchanged, the depth ratios all move by the factor."""
    ok = vis & np.isfinite(pos[..., 0])
    if not ok.any():
        return pos
    z = camera_depths(np.nan_to_num(pos), poses)
    f = float(np.exp(np.median(np.log(np.maximum(target[ok], 1e-6) / np.maximum(z[ok], 1e-6)))))
    centres = poses[:, :3, 3][None]
    return centres + f * (pos - centres)


def initial_motion(X: np.ndarray, vis: np.ndarray, ref: int, min_shared: int = 6) -> np.ndarray:
    """Object-to-world poses ``[T,4,4]`` of a group from its world positions ``X [n,T,3]``, chained frame to
    frame outwards from ``ref`` (identity there) by the rigid fit of the tracks seen in both; NaN where the chain
    breaks (fewer than ``min_shared`` tracks seen in two neighbouring frames)."""
    T = vis.shape[1]
    out = np.full((T, 4, 4), np.nan)
    out[ref] = np.eye(4)
    for step in (1, -1):
        t = ref + step
        while 0 <= t < T:
            k = vis[:, t] & vis[:, t - step]
            if k.sum() < min_shared:
                break
            out[t] = rigid_transform(X[k, t - step], X[k, t]) @ out[t - step]
            t += step
    return out


def _draw(idx: np.ndarray, weight: np.ndarray, k: int, rng, keys: np.ndarray | None) -> np.ndarray:
    """``k`` of the indices ``idx [n]`` (sorted), drawn without replacement with chances in proportion to ``weight
    [n]``. With ``keys [n]`` (uniform in (0, 1), fixed per track) the draw is Efraimidis and Spirakis': the ``k``
    largest ``log(key) / weight``. It has the distribution of sequential draws and changes by one track when the
    set changes by one, so the fits of one group's rounds share their tracks; else a fresh draw from ``rng``."""
    if keys is None:
        return np.sort(rng.choice(idx, k, replace=False, p=weight / weight.sum()))
    prio = np.log(np.clip(keys, 1e-300, 1.0)) / np.maximum(weight, 1e-12)
    return np.sort(idx[np.argpartition(-prio, k - 1)[:k]])


def key_frames(n: int, k: int) -> np.ndarray:
    """``min(n, k)`` positions ``[m]`` of ``n`` frames (sorted, 0 among them), spread evenly over them (all of them
    where ``k`` is 0 or ``n <= k``)."""
    if k <= 0 or n <= k:
        return np.arange(n)
    return np.unique(np.round(np.linspace(0, n - 1, k)).astype(np.int64))


def fit_motion(uv, vis, target, X, poses, K, cfg, s: RigidSettings, rng, dtype=torch.float64, device="cpu",
               iters: int | None = None, keys: np.ndarray | None = None):
    """Rigid motion of a group: ``uv [n,T,2]``, ``vis [n,T]``, ``target [n,T]`` depth targets (metres), ``X [n,T,3]``
    its stage-3 world positions (the start). Returns (the solved frames [F] int, their camera-from-object (R, t)
    tensors ``[F,3,3]``, ``[F,3]``; the object frame is the camera frame in the first of them), or None.
    ``iters``: Levenberg-Marquardt iterations (None: ``s.iters``). ``keys [n]``: the tracks' fixed uniform keys of
    :func:`_draw` (None: a fresh draw from ``rng``). Beyond ``s.max_fit_frames`` solved frames the bundle adjustment
    runs on that many key frames (:func:`key_frames`) and the others' poses are fitted to its points."""
    cfg = replace(cfg, lambda_dc=cfg.lambda_dc * s.dc_weight)
    ref = int(np.argmax(vis.sum(0)))
    O = initial_motion(X, vis, ref)  # object-to-world; the object frame is the world frame at ref
    frames = np.flatnonzero(np.isfinite(O[:, 0, 0]))
    if len(frames) < 3:
        return None
    pos = key_frames(len(frames), s.max_fit_frames)
    at_ref = int(np.searchsorted(frames, ref))
    key = frames[np.union1d(pos, [at_ref])]
    order = np.concatenate([[ref], key[key != ref]])  # stage 2 keeps its frame 0 fixed
    # [T,4,4] camera-from-object (NaN in the unsolved frames), the object frame moved to the camera's at ref
    cfo = invert_pose(poses) @ O @ poses[ref]
    seen = vis[:, order].sum(1)  # each track's solved frames
    fit = np.flatnonzero(seen >= 2)
    if len(fit) < 3:
        return None
    if len(fit) > s.max_fit:  # drawn with a chance in proportion to the frames each is seen in (see RigidSettings)
        fit = _draw(fit, seen[fit], s.max_fit, rng, None if keys is None else keys[fit])
    p = stage2.BAProblem.from_tracks(uv[np.ix_(fit, order)], target[np.ix_(fit, order)], vis[np.ix_(fit, order)], K,
                                     cfg, dtype, device)
    R, t = lie.c2w_to_w2c(invert_pose(cfo[order]), dtype, device)  # camera-from-object as (R, t)
    sol = stage2.solve_lm(R, t, stage2.init_points(R, t, p), p, iters=iters or s.iters)
    if len(order) == len(frames):
        return order, sol.R, sol.t
    # the other frames: each one's chained pose relative to the nearest key frame's carried onto that frame's fit,
    # then fitted to the bundle adjustment's points
    rest = np.setdiff1d(frames, order)
    kf = np.sort(order)
    after = np.clip(np.searchsorted(kf, rest), 1, len(kf) - 1)
    near = np.where(rest - kf[after - 1] <= kf[after] - rest, kf[after - 1], kf[after])
    fitted = np.full_like(cfo, np.nan)  # [T,4,4] the key frames' camera-from-object of the fit
    fitted[order] = pose_from_rt(sol.R.detach().cpu().numpy(), sol.t.detach().cpu().numpy())
    start = cfo[rest] @ invert_pose(cfo[near]) @ fitted[near]
    q = stage2.BAProblem.from_tracks(uv[np.ix_(fit, rest)], target[np.ix_(fit, rest)], vis[np.ix_(fit, rest)], K,
                                     cfg, dtype, device)
    R0 = torch.as_tensor(start[:, :3, :3], dtype=dtype, device=device)
    t0 = torch.as_tensor(start[:, :3, 3], dtype=dtype, device=device)
    Rr, tr = stage2.fit_poses(R0, t0, sol.X, q, iters=iters or s.iters)
    return np.concatenate([order, rest]), torch.cat([sol.R, Rr]), torch.cat([sol.t, tr])


def place_on_motion(uv, vis, target, motion, K, cfg, dtype=torch.float64, device="cpu", rows=None):
    """Tracks ``uv [N,T,2]`` (an array or :class:`Rows`), ``vis [N,T]``, ``target [N,T]`` (those of ``rows [n]``;
    None: all) fitted as points of a rigid ``motion`` (:func:`fit_motion`). Returns (their points ``[n,3]`` in the
    object frame (:func:`object_positions` places them on :func:`motion_poses`); median and 80th percentile of the
    reprojection error ``[n,2]`` px over the solved frames a track is seen in, inf where fewer than 3; median
    ``|log(depth / target)|`` ``[n]`` over those frames, NaN where none)."""
    order, R, t = motion
    if not stage2.compiled(R):  # the motion is solved in dtype on device (fit_motion)
        if rows is not None:
            uv, vis, target = uv[rows], vis[rows], target[rows]
        elif isinstance(uv, Rows):
            uv = uv.copy()
        return _place_on_motion_torch(uv, vis, target, motion, K, cfg, dtype, device)
    # the same steps compiled for the CPU (optim.point_fit): 10x faster
    rows = np.arange(len(vis)) if rows is None else rows
    px, px_rows = _pixel_rows(uv, rows)
    return point_fit.fit_and_score(R.detach().numpy(), t.detach().numpy(), K, px, target, vis,
                                   (cfg.lambda_ba, 0.0 if cfg.no_depth_consistency else cfg.lambda_dc, cfg.lambda_asap),
                                   not cfg.no_offsets, cfg.dc_space == "log", rows=rows, frames=order, px_rows=px_rows)


def _place_on_motion_torch(uv, vis, target, motion, K, cfg, dtype=torch.float64, device="cpu"):
    """:func:`place_on_motion` in torch, on any device (stage 2's :func:`~trackingworld.optim.stage2.fit_points`)."""
    order, R, t = motion
    n = len(vis)
    pa = stage2.BAProblem.from_tracks(uv[:, order], target[:, order], vis[:, order], K, cfg, dtype, device)
    P = stage2.fit_points(R, t, pa)
    Y, r_uv, _ = stage2.residuals(R, t, P, pa)
    pt, fr = pa.pt.cpu().numpy(), pa.fr.cpu().numpy()  # the problem's observations (frames index ``order``)
    q, counts = stage2.point_quantiles(r_uv.norm(dim=-1).detach().cpu().numpy(), pt, n, (0.5, 0.8))
    med = np.where(counts[:, None] >= 3, q, np.inf)
    # the camera depth of the point on the motion is the fit's own camera z
    dz = _log_ratio(Y[:, 2].detach().cpu().numpy().astype(np.float64), target[:, order][pt, fr])
    return P.detach().cpu().numpy().astype(np.float64), med, stage2.point_medians(dz, pt, n)


def motion_poses(motion, poses: np.ndarray, T: int) -> np.ndarray:
    """Object-to-world poses ``[T,4,4]`` of a rigid ``motion`` (:func:`fit_motion`), NaN in the frames it is not
    solved in."""
    order, R, t = motion
    out = np.full((T, 4, 4), np.nan)
    out[order] = poses[order] @ invert_pose(lie.w2c_to_c2w(R, t))
    return out


def object_positions(P: np.ndarray, to_world: np.ndarray) -> np.ndarray:
    """World positions ``[n,T,3]`` of points ``P [n,3]`` of the object frame under object-to-world poses
    ``to_world [T,4,4]``, NaN where those are."""
    out = np.full((len(P), len(to_world), 3), np.nan)
    known = np.flatnonzero(np.isfinite(to_world[:, 0, 0]))
    out[:, known] = transform(to_world[known][None], P[:, None, :])
    return out


def rigid_movers(uv: np.ndarray, vis: np.ndarray, target: np.ndarray, xyz: np.ndarray, poses: np.ndarray,
                 K: np.ndarray, qf: np.ndarray, cfg, s: RigidSettings, log=None, dtype=torch.float64,
                 device="cpu", size: tuple[int, int] | None = None,
                 into: Callable[[], np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """World positions ``[N,T,3]`` of dynamic tracks with every rigidly moving group placed by its rigid motion
    (stage 3's ``xyz [N,T,3]`` elsewhere; the module docstring says how groups are found). ``uv [N,T,2]``,
    ``vis [N,T]``, ``target [N,T]`` stage 3's depth targets (metres), ``qf [N]`` query frames, ``cfg`` the
    optimiser's config (the fit's weights and kernels), ``size`` the image's (W, H), which the joining of groups
    across a gap needs (``s.bridge``; :mod:`trackingworld.optim.rigid_bridge`). Returns the positions, each track's
    object ``[N]`` (-1: none; an index into the next), the objects' object-to-world poses ``[G,T,4,4]`` (groups joined
    across a gap are one object; NaN in the frames its motion is not solved in; the object frame is the camera frame
    at the frame its first group's fit was referred to) and counts. ``into``: called once the
    groups are found, the ``[N,T,3]`` array the groups' positions are written into and returned (None: a copy of
    ``xyz``); ``xyz`` is read only at the visible frames and the query frames. ``uv`` and ``xyz`` may be float32
    (the pipeline's, 20 bytes an observation less than float64 copies): every computation reads them in float64
    (a subset cast, or a float64 term beside them), so the numbers are those of float64 inputs. They may also be
    :class:`Rows` of the pipeline's arrays of every track (read in place: the same numbers); ``out`` is then a new
    array."""
    N, T = vis.shape
    target = np.ascontiguousarray(target, np.float64)  # once, not at each membership test (optim.point_fit)
    z = CameraDepths(xyz, poses)
    rng = np.random.default_rng(s.rng_seed)
    keys = rng.random(N) if s.keyed_draw else None
    seen = vis.sum(1)
    left = seen >= s.min_seen
    pairs = neighbour_pairs(uv, vis, z, qf, s)
    adj = coo_matrix((np.ones(2 * len(pairs)), (np.r_[pairs[:, 0], pairs[:, 1]], np.r_[pairs[:, 1], pairs[:, 0]])),
                     shape=(N, N)).tocsr()

    def explained(idx, motion):
        """(bool [len(idx)]: the tracks ``idx`` the motion explains; the points ``[k,3]`` of those k on it)"""
        P, med, dz = place_on_motion(uv, vis, target, motion, K, cfg, dtype, device, rows=idx)
        with np.errstate(invalid="ignore"):  # NaN: a track seen in no solved frame, not explained
            ok = (med[:, 0] <= s.max_px) & (med[:, 1] <= s.max_px80) & (dz <= s.depth_tol)
        return ok, P[ok]

    def grow(seed, motion):
        """The remaining tracks the motion explains that are joined to ``seed`` through explained neighbours
        (region growing over ``pairs``: each track is tested once), and their points ``[n,3]`` on the motion."""
        tested = np.zeros(N, bool)
        inl = np.zeros(N, bool)
        pts = np.zeros((N, 3))
        front = np.asarray(seed)
        while len(front):
            front = front[left[front] & ~tested[front]]
            if not len(front):
                break
            tested[front] = True
            ok, P = explained(front, motion)
            inl[front[ok]] = True
            pts[front[ok]] = P
            nxt = adj[front[ok]].indices
            front = np.unique(nxt)
        members = np.flatnonzero(inl)
        return members, pts[members]

    def refit(members, iters=None, draws=None):
        """The rigid motion of the tracks ``members`` (:func:`fit_motion`; ``iters`` None: the full fit; ``draws``
        the generator of its draw, None: the search's)."""
        return fit_motion(uv[members].astype(np.float64), vis[members], target[members],
                          xyz[members].astype(np.float64), poses, K, cfg, s,
                          rng if draws is None else draws, dtype, device, iters,
                          None if keys is None else keys[members])

    def settled(grown, members) -> bool:
        """Whether a group changed by no more than ``settle`` of its tracks from ``members`` to ``grown``."""
        return len(np.setxor1d(grown, members)) <= s.settle * len(members)

    def try_seed(i):
        """(members [n], their points [n,3] on the motion, the motion) of the group grown from the seed track ``i``,
        and the seed patch; the group None where it has fewer than ``min_tracks`` or no motion is found."""
        t = int(qf[i])
        pool = np.flatnonzero(left & vis[:, t])
        pool = pool[_log_ratio(z[pool, t], z[i, t]) <= s.depth_tol]
        near = pool[np.argsort(np.linalg.norm(uv[pool, t].astype(np.float64) - uv[i, t], axis=1))[: s.seed_tracks]]
        members = near
        for _round in range(s.rounds):
            motion = refit(members, s.round_iters)
            if motion is None:
                break
            grown, _ = grow(near, motion)
            done = settled(grown, members)
            members = grown
            if len(members) < s.min_tracks or done:
                break
        if motion is None or len(members) < s.min_tracks:
            return None, near
        # the group's motion fitted to it in full, then again while the group that fit grows keeps changing
        for k in range(1 + s.final_rounds):
            again = refit(members)
            if again is None:
                if k == 0:
                    return None, near
                break
            motion = again
            grown, P = grow(members, motion)
            done = settled(grown, members) or len(grown) < s.min_tracks
            members = grown
            if done:
                break
        if (s.split_gap > 0 or s.relay_gap > 0) and len(members) >= s.min_tracks:
            members, P, motion = one_piece(members, P, motion)
        return ((members, P, motion) if motion is not None and len(members) >= s.min_tracks else None), near

    def one_piece(members, P, motion):
        """The group cut to its largest piece in the object frame (:func:`pieces`) where the others hold
        ``split_share`` of it or more, or else to the larger of two objects handed over (:func:`handed_over`),
        its motion fitted to that piece again and the group grown from it again
        (cut once more, not grown, if it is two pieces again): two objects that one rigid motion explains over the
        frames both are seen in (a spin about an axis between two objects that pass each other the opposite way),
        the group then placing each in the frames where only the other is seen."""
        for again in (True, False):
            if not np.isfinite(P).all():
                break
            depth = float(np.median(z[members, qf[members]]))
            keep = None
            if s.split_gap > 0:
                label = pieces(P, s.split_gap * depth)
                sizes = np.bincount(label)
                big = int(np.argmax(sizes))
                if sizes[big] <= (1 - s.split_share) * len(members):
                    keep = label == big
                    if log:
                        log(f"group of {len(members)} tracks cut to its largest piece of {sizes[big]} "
                            f"({len(sizes)} pieces {s.split_gap * depth:.2f} m apart)")
            if keep is None and s.relay_gap > 0:
                early = handed_over(uv, vis, members, P, motion, K, s, depth)
                if early is not None:
                    earlier = early.sum() >= len(early) / 2  # the larger set kept
                    keep = early if earlier else ~early
                    if log:
                        log(f"group of {len(members)} tracks cut to its {'earlier' if earlier else 'later'} "
                            f"{keep.sum()}: two objects, one lost where the other's tracks begin")
            if keep is None:
                break
            piece = members[keep]
            # drawn from a generator of its own: the search's stream, which every later group's fits draw from, stays
            # the one it would be without the cut
            motion = refit(piece, draws=np.random.default_rng(s.rng_seed + 1))
            if motion is None:
                return piece, P, None
            if again:
                members, P = grow(piece, motion)
            else:
                ok, P = explained(piece, motion)
                members = piece[ok]
        return members, P, motion

    objects: list[RigidObject] = []
    info = {"rigid_groups": 0, "rigid_tracks": 0, "rigid_seeds": 0}
    seeds = left.copy()
    tried = []  # the seed patches and groups of the first pass
    passes = [(s.max_seeds, s.max_failed, False)]
    if s.ring_seeds:
        passes.append((s.ring_seeds, s.ring_failed, True))
    for n_seeds, max_failed, ring in passes:
        if ring and tried:  # the second pass: no seed near what the first one tried
            seeds[_ring(adj, np.unique(np.concatenate(tried)), s.seed_ring)] = False
        failed = 0
        for _ in range(n_seeds):
            cand = np.flatnonzero(seeds & left)
            if left.sum() < s.min_tracks or not len(cand):
                break
            info["rigid_seeds"] += 1
            i = int(cand[np.argmax(seen[cand])])  # the longest remaining track
            group, near = try_seed(i)
            seeds[near] = False
            here = [near] if group is None else [near, group[0]]  # this seed's patch and group
            if ring:
                seeds[_ring(adj, np.concatenate(here), s.seed_ring)] = False
            else:
                tried += here
            if group is None:
                failed += 1
                if failed >= max_failed:
                    break
                continue
            failed = 0
            members, P, motion = group
            O = motion_poses(motion, poses, T)
            objects.append(RigidObject(O, members, P, np.repeat(np.isfinite(O[None, :, 0, 0]), len(members), 0)))
            left[members] = False
            info["rigid_groups"] += 1
            info["rigid_tracks"] += int(len(members))
            if log:
                log(f"group {info['rigid_groups']}: {len(members)} tracks in {len(motion[0])} frames "
                    f"(seed {info['rigid_seeds']}{', the second pass' if ring else ''})")
    if s.bridge is not None and size is not None:
        n = len(objects)
        objects = bridge(objects, uv, vis, xyz, poses, K, size, s.bridge, log)
        info["rigid_joined"] = n - len(objects)
    out = xyz.copy() if into is None else into()  # Rows.copy(): its rows copied out
    groups = np.full(N, -1)
    motions = np.full((len(objects), T, 4, 4), np.nan)
    for g, o in enumerate(objects):
        groups[o.members] = g
        motions[g] = o.motion
        pos = object_positions(o.points, o.motion)
        if s.median_scale:
            pos = _to_median_scale(pos, vis[o.members], target[o.members], poses)
        # a track takes the motion's positions in its own group's frames, and in the frames it is hidden in where
        # groups were joined: where it is seen there, its own observations placed it (stage 3)
        keep = np.isfinite(pos[..., 0]) & (o.own | ~vis[o.members])
        sub = out[o.members]
        sub[keep] = pos[keep]
        out[o.members] = sub
    return out, groups, motions, info


def handed_over(uv, vis: np.ndarray, rows: np.ndarray, P: np.ndarray, motion, K: np.ndarray, s: RigidSettings,
                depth: float) -> np.ndarray | None:
    """``[n] bool``: the earlier of two sets of a group's tracks that are two objects handed over from one to the
    other, or None (``RigidSettings.relay_gap``). ``uv [N,T,2]`` px (an array or :class:`Rows`), ``vis [N,T]``;
    ``rows [n]`` the group's tracks, ``P [n,3]`` their points in the object frame (metres) on the rigid ``motion``
    (:func:`fit_motion`), ``depth`` the group's median depth (metres). A track is explained in a solved frame where
    its point projects within ``max_px80`` of it; the frame after which fewest tracks are explained in 3 or more
    frames on both sides, relative to the smaller side (each of ``min_tracks`` or more), parts them, by the middle
    of each track's explained frames. Read frame by frame: a few bytes a track at a time."""
    order, R, t = motion
    R = R.detach().cpu().numpy().astype(np.float64)
    t = t.detach().cpu().numpy().astype(np.float64)
    T = vis.shape[1]
    ok = np.zeros((len(rows), T), bool)
    for k, f in enumerate(np.asarray(order)):
        sel = np.flatnonzero(vis[rows, f])
        if not len(sel):
            continue
        px, z = project(P[sel] @ R[k].T + t[k], K)
        ok[sel, f] = (z > 1e-6) & (np.linalg.norm(px - uv[rows[sel], f], axis=-1) <= s.max_px80)
    upto = np.cumsum(ok, 1)[:, :-1]  # [n,T-1] explained frames up to and including each frame
    before, after = upto >= 3, (ok.sum(1, keepdims=True) - upto) >= 3
    side = np.minimum(before.sum(0), after.sum(0))
    valid = side >= s.min_tracks
    if not valid.any():
        return None
    share = (before & after).sum(0) / np.maximum(side, 1)
    b = int(np.flatnonzero(valid)[np.argmin(share[valid])])
    if share[b] >= s.relay_share:
        return None
    frames = np.arange(T)
    early = np.array([np.median(frames[o]) <= b if o.any() else False for o in ok])  # by the middle of its frames
    if early.sum() < s.min_tracks or (~early).sum() < s.min_tracks:
        return None
    gap = s.relay_gap * depth
    for a, c in ((early, ~early), (~early, early)):
        d, _ = cKDTree(P[a]).query(P[c], k=1, distance_upper_bound=gap)
        if np.isfinite(d).mean() >= s.relay_touch:
            return None  # they meet: one object whose later tracks were picked up where the earlier were lost
    return early


def pieces(P: np.ndarray, gap: float) -> np.ndarray:
    """``[n]`` int: the connected piece of each point ``P [n,3]`` (metres), points in the same or touching cubes of
    side ``gap`` joined (26 neighbours): two points within ``gap`` of each other are always joined, two more than
    ``2 * sqrt(3) * gap`` apart never directly. Linear in the points, unlike the pairs within a radius of a dense
    cloud (scipy's connected components over the occupied cubes)."""
    cell = np.floor(P / gap).astype(np.int64)
    cell -= cell.min(0) - 1  # every neighbour's coordinate stays >= 0
    span = cell.max(0) + 2
    key = (cell[:, 0] * span[1] + cell[:, 1]) * span[2] + cell[:, 2]
    cubes, of = np.unique(key, return_inverse=True)
    rows, cols = [], []
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                if (dx, dy, dz) <= (0, 0, 0):  # each pair of touching cubes once, from one side
                    continue
                near = cubes + (dx * span[1] + dy) * span[2] + dz
                at = np.minimum(np.searchsorted(cubes, near), len(cubes) - 1)
                hit = cubes[at] == near
                rows.append(np.flatnonzero(hit))
                cols.append(at[hit])
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    g = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(cubes), len(cubes)))
    return connected_components(g, directed=False)[1][of.reshape(-1)]
