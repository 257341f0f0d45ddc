"""Where a dynamic track is not visible: carried by the motion of its neighbours on the same object.

Stage 3 places a dynamic track only where it is observed. Holding its last position through the frames it is
hidden (lost by the tracker, occluded, outside the image) leaves it behind while its object moves on.

Carrying: for a hidden frame t of track i, with s its nearest visible frame, ``x_i(t) = x_i(s) + step`` with the
step the weighted median, coordinate by coordinate, of the donors' steps ``x_j(t) - x_j(s)`` over its k nearest
tracks at frame s (3D) among the tracks visible at both s and t, weights 1 / (distance + 1 cm), those farther
than ``reach`` metres and twice the nearest one's distance left out (a donor on another object). A rigid object's
translation is carried exactly, its rotation to first order in the donors' spread. A frame with no track visible
at both s and t keeps the held position ``x_i(s)``. The median (``stat``) rather than the weighted mean: about one
donor in five of a long gap is on another object (`hard` seed 0, its 8 nearest by 3D distance: 81% on the
track's own), and one such donor drags a mean along; ten synthetic scenes, dynamic world accuracy on the mean
(README, stop 40).

The donors are looked for among the tracks visible at both frames, not among the track's nearest neighbours at
s: dense tracks lost by the 2D tracker are lost in bunches, and the nearest ones at s are then hidden at t too
(on two synthetic scenes 57% and 71% of the hidden observations had none of their 16 nearest visible at t, and
were held). Ten synthetic scenes: world accuracy of the dynamic tracks 67.8 -> 69.0 on the mean (README).

Nearness at s is measured with the image motion too (``motion_scale`` > 0): the distance is taken over
``[x(s), motion_scale * v(s)]``, v the track's 2D velocity at s (px per frame, to the previous frame or from the
next one, where visible), so that of two objects passing each other at s the donors come from the one
moving like the track. On `hard` scene 0 about half of the donors by 3D distance alone were on another object
(movers crossing in front of the camera). A track seen in no neighbouring frame of s (a track seen once) takes
the inverse-distance mean velocity of its 4 nearest tracks at s in 3D that have one (``_impute_velocity``).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
from scipy.spatial import cKDTree

from trackingworld.config import CARRY_STATS
from trackingworld.optim.parallel import worker_threads
from trackingworld.tracking2d.base import nearest_visible_frame

MAX_DONORS = 2000  # tracks visible at both frames used per (s, t) pair: an even thinning beyond this (speed)
SOFT_M = 0.01  # metres added to the donors' distances in their weights
# approximate kNN (scipy's eps: each donor within (1 + EPS) x the exact one's distance): 25% faster on a 48-frame
# scene, world accuracy within 0.05 of the exact search on three scenes (the weights fall off with distance)
EPS = 1.0
# the donors are searched at every gap (frames from the anchor) up to DENSE_GAPS, then at gaps growing by GAP_RATIO;
# the frames between take interpolated steps. 120 frames (4.96M hidden observations, 36 of 119 gaps searched):
# 10.7 -> 6.4-7.0 s, world accuracy 80.57 -> 80.46; ten 32-48-frame scenes within 0.1 of searching every gap.
# Sparser schedules lost more accuracy (every gap to 4, then x1.41: 4.3 s but -0.7; to 8, then x1.25: -0.5)
DENSE_GAPS = 12
GAP_RATIO = 1.1
CHUNK = 1 << 14  # tracks per chunk of the interpolation
# the searches are many and small (120 frames: 5,888 frame pairs, 450 queries each on the mean): one thread each
# (scipy's threads cost more to start than they save) and trees built unbalanced without compacting the nodes
# (a third less to build, the queries as fast), positions kept in float32 but per pair: the carrying there 6.4-7.8 s
# (four runs) -> 4.6-5.2 s (three), world accuracy 80.46 -> 80.43; six 32-48-frame scenes within 0.04
TREE = dict(balanced_tree=False, compact_nodes=False)
# the (s, t) pairs are shared among optim.parallel.worker_threads() threads (scipy's kNN and numpy's larger
# operations release the GIL): 120 frames, 5,888 pairs on 2 cores: 3.72 -> 2.58 s for the searches, the same steps
# to the bit (README)


def searched_gaps(T: int, dense: int = DENSE_GAPS, ratio: float = GAP_RATIO) -> np.ndarray:
    """[g] int: the gaps (frames from the anchor) at which the donors are searched: every one up to ``dense``,
    then each about ``ratio`` times the one before, up to T - 1 (defaults, T = 120: 1 to 12, 13, 15, 16, 18, ...,
    98, 107, 118)."""
    out, g = list(range(1, min(dense, T - 1) + 1)), float(dense)
    while True:
        g = max(g * ratio, g + 1)
        if round(g) > T - 1:
            return np.asarray(out, np.int64)
        out.append(int(round(g)))


def image_velocity(uv: np.ndarray, vis: np.ndarray, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Each track's 2D velocity at each frame where it and a neighbouring frame are visible, ``[T,N,2]`` float32 px
    per frame (frames first, the layout of the carrying's searches): to the previous frame, else from the next;
    and ``[T,N]`` bool where it is known (elsewhere 0). ``uv [M,T,2]`` px (``rows [N]``: the tracks are those rows;
    None: all, M = N), ``vis [N,T]``. Frame by frame: no ``[T,N,2]`` array beside the result (the carrying's peak
    on a long video)."""
    N, T = vis.shape
    seen = np.ascontiguousarray(vis.T)
    vel = np.zeros((T, N, 2), np.float32)
    known = np.zeros((T, N), bool)

    def pixels(t):
        return np.asarray(uv[:, t] if rows is None else uv[rows, t], np.float32)

    back = np.zeros(N, bool)  # visible at the frame before with the one before that
    after = pixels(0) if T > 1 else None
    for t in range(1, T):
        before, after = after, pixels(t)
        step = after - before  # [N,2] from frame t - 1 to t
        pair = seen[t] & seen[t - 1]
        vel[t] = np.where(pair[:, None], step, np.float32(0))  # to the previous frame
        fwd = pair & ~back  # frame t - 1: else from the next one (never both)
        vel[t - 1] += np.where(fwd[:, None], step, np.float32(0))
        known[t] |= pair
        known[t - 1] |= fwd
        back = pair
    return vel, known


def _impute_velocity(vel: np.ndarray, known: np.ndarray, pos: np.ndarray, vis_t: np.ndarray, k: int = 4) -> None:
    """In place: the velocity ``vel [T,N,2]`` of each visible track where it is not ``known [T,N]`` (seen in no
    neighbouring frame: a track seen once) becomes the inverse-distance-weighted mean of its ``k`` nearest tracks'
    at that frame in 3D (``pos [T,N,3]``) among those with a known one; ``vis_t [T,N]``."""
    for t in range(len(vel)):
        miss = np.flatnonzero(vis_t[t] & ~known[t])
        have = np.flatnonzero(known[t])
        if not len(miss) or not len(have):
            continue
        kk = min(k, len(have))
        d, j = cKDTree(pos[t, have].astype(np.float64), **TREE).query(pos[t, miss].astype(np.float64), k=kk,
                                                                     workers=1, eps=EPS)
        w = 1.0 / (d.reshape(len(miss), kk) + SOFT_M)
        vel[t, miss] = np.einsum("ck,ckd->cd", w, vel[t, have][j.reshape(len(miss), kk)]) / w.sum(1, keepdims=True)


def weighted_median(v: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``[n,d]``: per row and coordinate, the weighted median of ``v [n,k,d]`` under the weights ``w [n,k]``
    (>= 0, a positive sum per row): the smallest value whose cumulative weight, in sorted order, reaches half of
    its row's total."""
    n, k, d = v.shape
    rows = v.transpose(0, 2, 1).reshape(n * d, k)  # one row per (track, coordinate): sorted along its k values
    order = np.argsort(rows, axis=1)
    r = np.arange(n * d)
    cum = np.cumsum(w[r[:, None] // d, order], axis=1)
    pick = (cum >= 0.5 * cum[:, -1:]).argmax(1)  # the rank of the median
    return rows[r, order[r, pick]].reshape(n, d)


def donor_step(at_s: np.ndarray, at_t: np.ndarray, donors: np.ndarray, i: np.ndarray, k: int, reach: float,
               max_donors: int = MAX_DONORS, motion_s: np.ndarray | None = None,
               stat: str = "median") -> np.ndarray | None:
    """The step ``[n,3]`` float32 (metres) from frame s to frame t of the tracks ``i`` [n] (indices), the weighted
    ``stat`` (median: per coordinate; or mean) of the steps of their ``k`` nearest ``donors`` (indices of tracks
    visible at both frames, evenly thinned to ``max_donors``) at s, by the module docstring's weights. ``at_s``,
    ``at_t`` [N,3] every track's position at s and t (float32 world metres; only the donors' and, at s, the
    tracks' are read). ``motion_s`` [N,2] (metres): every track's scaled image velocity at s, searched with the
    position when given. None without donors."""
    if not len(donors):
        return None
    if len(donors) > max_donors:
        donors = donors[:: -(-len(donors) // max_donors)]
    kk = min(k, len(donors))
    moved = at_t[donors].astype(np.float64) - at_s[donors]  # [m,3] each donor's motion from s to t
    feat, query = at_s[donors], at_s[i]
    if motion_s is not None:
        feat = np.concatenate([feat, motion_s[donors]], 1)
        query = np.concatenate([query, motion_s[i]], 1)
    d, j = cKDTree(feat.astype(np.float64), **TREE).query(query.astype(np.float64), k=kk, workers=1, eps=EPS)
    d, j = d.reshape(len(i), kk), j.reshape(len(i), kk)
    w = np.where(d <= np.maximum(reach, 2 * d[:, :1]), 1.0 / (d + SOFT_M), 0.0)
    if stat == "median":
        return weighted_median(moved[j], w).astype(np.float32)
    return (np.einsum("ck,ckd->cd", w, moved[j]) / w.sum(1, keepdims=True)).astype(np.float32)


def carry_hidden(xyz: np.ndarray, vis: np.ndarray, k: int = 8, reach: float = 0.3,
                 max_donors: int = MAX_DONORS, threads: int | None = None, uv: np.ndarray | None = None,
                 motion_scale: float = 0.0, stat: str = "median", rows: np.ndarray | None = None,
                 overwrite: bool = False) -> np.ndarray:
    """Tracks ``xyz [N,T,3]`` (world metres; only the visible frames ``vis [N,T]`` are read) with every hidden
    frame carried by its donors' motion (module docstring: ``k`` donors, ``reach`` metres, their steps combined
    by ``stat``, one of CARRY_STATS). The donors are
    searched at the gaps of :func:`searched_gaps` from the anchor; a hidden frame in between takes the step
    interpolated linearly between the searched frames on either side of it (the first and last frames of the
    video are searched from every anchor; where no searched frame follows in the same run of hidden frames, the
    step of the one before). Tracks never visible are returned as given. The searches run on ``threads``
    threads (None: ``optim.parallel.worker_threads``); the result does not depend on it. ``uv [N,T,2]`` (px) with
    ``motion_scale`` > 0 (metres per px per frame): donors searched with the image motion too (module docstring);
    ``rows [N]``: the tracks are those rows of ``uv [M,T,2]`` (not copied out). Returns a new ``[N,T,3]`` array of
    xyz's dtype, or with ``overwrite`` ``xyz`` itself, written in place (one ``[N,T,3]`` array fewer at the peak)."""
    if stat not in CARRY_STATS:
        raise ValueError(f"stat: {stat!r} is not {' or '.join(CARRY_STATS)}")
    N, T = vis.shape
    src = nearest_visible_frame(vis)  # [N,T]
    if overwrite:  # held at the nearest visible frame (carried below), a chunk of tracks at a time
        out = xyz
        for a in range(0, N, CHUNK):
            out[a:a + CHUNK] = np.take_along_axis(xyz[a:a + CHUNK], src[a:a + CHUNK, :, None], axis=1)
    else:
        out = np.take_along_axis(xyz, src[..., None], axis=1)
    if T < 2:
        return out
    vis_t = np.ascontiguousarray(vis.T)  # [T,N]
    # [T,N,3] float32, per pair in float64 below; read at the visible frames only, where ``out`` is still ``xyz``,
    # and before ``out`` is written: float32 positions are read where they are (a frames-first copy would hold 12
    # bytes an observation more at the carrying's peak, and the searches beside the rigid step do not set its time)
    pos = out.transpose(1, 0, 2) if out.dtype == np.float32 else np.ascontiguousarray(out.transpose(1, 0, 2),
                                                                                         dtype=np.float32)
    seen = vis.any(1)
    motion = None  # [T,N,2] metres: every visible track's scaled image velocity (known or imputed)
    if uv is not None and motion_scale > 0:
        motion, known = image_velocity(uv, vis, rows)
        _impute_velocity(motion, known, pos, vis_t)
        motion *= np.float32(motion_scale)
    gaps = searched_gaps(T)
    searched = np.zeros(T, bool)
    searched[gaps] = True
    # frames first (each pair's tracks are written along a contiguous row): the step added to the held positions,
    # the donors' at the searched hidden frames (where there were donors: done), interpolated between them below
    step = np.zeros((T, N, 3), np.float32)
    done = np.zeros((T, N), bool)
    pairs = []  # (s, t, the tracks hidden at t with anchor s)
    for t in range(T):
        hidden = np.flatnonzero(~vis_t[t] & seen)
        if 0 < t < T - 1:  # the first and last frames are searched from every anchor (the runs' ends)
            hidden = hidden[searched[np.abs(t - src[hidden, t])]]
        if not len(hidden):
            continue
        anchor = src[hidden, t]
        order = np.argsort(anchor, kind="stable")
        hidden, anchor = hidden[order], anchor[order]
        cuts = np.flatnonzero(np.diff(anchor)) + 1
        pairs += [(int(anchor[who[0]]), t, hidden[who]) for who in np.split(np.arange(len(hidden)), cuts)]

    def pair_step(pair):
        s, t, i = pair
        return donor_step(pos[s], pos[t], np.flatnonzero(vis_t[s] & vis_t[t]), i, k, reach, max_donors,
                          None if motion is None else motion[s], stat)

    with ThreadPoolExecutor(worker_threads() if threads is None else threads) as pool:
        for (_, t, i), st in zip(pairs, pool.map(pair_step, pairs), strict=True):
            if st is not None:
                step[t, i] = st
                done[t, i] = True
    # the hidden frames between searched ones: linear in the gap between the searched frames around them
    below = np.maximum.accumulate(np.where(searched, np.arange(T), 0))  # [T] largest searched gap <= g
    above = np.minimum.accumulate(np.where(searched, np.arange(T), T)[::-1])[::-1]  # smallest >= g
    for a in range(0, N, CHUNK):
        hi, ht = np.nonzero(~vis[a:a + CHUNK] & seen[a:a + CHUNK, None])
        hi += a
        s = src[hi, ht]
        g = np.abs(ht - s)
        between = ~searched[g] & (ht > 0) & (ht < T - 1)  # the others were searched above
        hi, ht, s, g = hi[between], ht[between], s[between], g[between]
        sign = np.sign(ht - s)
        g1 = below[g]
        t1, t2 = s + sign * g1, np.clip(s + sign * above[g], 0, T - 1)  # past the video's end: its last frame
        g2 = np.abs(t2 - s)
        ok1 = (g1 > 0) & done[t1, hi]
        ok2 = (src[hi, t2] == s) & done[t2, hi]  # done: hidden there and searched
        frac = ((g - g1) / np.maximum(g2 - g1, 1))[:, None]
        s1, s2 = step[t1, hi], step[t2, hi]
        mid = np.where((ok1 & ok2)[:, None], s1 + frac * (s2 - s1), np.where(ok1[:, None], s1, s2))
        use = ok1 | ok2
        step[ht[use], hi[use]] = mid[use]  # never a searched frame: those read above stay the donors'
    out += step.transpose(1, 0, 2).astype(out.dtype, copy=False)
    return out
