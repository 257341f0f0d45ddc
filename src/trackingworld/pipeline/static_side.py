"""Which tracks are static, and where their points are, once stage 2 has fixed the poses (paper Sec. 3.3 and
appendix, with this package's own tests): the mask-dynamic and ambiguous tracks tested as static, the static
tracks outside stage 2 rebuilt from its points or fitted, the short tracks voted on by the tested ones, and the
static observations off their point left out. Each step updates the run's labels ``dynamic [N]`` and world
positions ``xyz [N,T,3]`` in place and returns the visibility ``[N,T]`` it leaves (a slipped track keeps its run).
Conventions: ``uv [N,T,2]`` px, ``vis [N,T]``, depths ``[N,T]`` metres, poses camera-to-world ``[T,4,4]``."""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cache

import cv2
import numpy as np
import torch

from trackingworld.config import OptimConfig
from trackingworld.geometry import camera_depths, nearest_pixel, transform, unproject
from trackingworld.image import blurred_frames
from trackingworld.optim.densify import cell_representatives, propagate_ratio
from trackingworld.optim.labels import AMBIGUOUS, DYNAMIC, STATIC, mask_regions
from trackingworld.optim.occluded_static import static_behind_occluders
from trackingworld.optim.photo_static import (
    MASK_MARGIN_PX,
    colour_shares,
    depth_scales,
    near_masks,
    static_hypothesis,
)
from trackingworld.optim.static_tests import (
    fit_static_points,
    fits_static_chunked,
    rescue_slipped,
    static_outliers,
    vote_short,
)

VOTE_CELL_PX = 4  # the tracks a short track is voted on by: one per (query frame, 4 px square)


@dataclass
class StaticFits:
    """What every static fit after stage 2 reads: the tracks ``uv [N,T,2]`` px, their depth target ``D [N,T]``
    metres (the prior, field-corrected with ``prior_field``), K, the poses held (``R [T,3,3]``, ``t [T,3]``
    world-to-camera tensors), the config and the device."""

    uv: np.ndarray
    D: np.ndarray
    K: np.ndarray
    R: torch.Tensor
    t: torch.Tensor
    cfg: OptimConfig
    device: str

    def test(self, tracks, vis):
        """:func:`~trackingworld.optim.static_tests.fits_static_chunked`: (still [n], X [n,3], worst px [n])."""
        return fits_static_chunked(tracks, self.uv, self.D, vis, self.K, self.R, self.t, self.cfg, self.device)

    def rescue(self, tracks, still, X, px, vis, qf):
        """:func:`~trackingworld.optim.static_tests.rescue_slipped`: (visibility, tracks rescued)."""
        return rescue_slipped(tracks, still, X, px, self.uv, self.D, vis, qf, self.K, self.R, self.t, self.cfg,
                              self.device)

    def fit(self, tracks, vis, xyz, cfg: OptimConfig | None = None, iters: int = 6) -> None:
        """``xyz[tracks]`` <- their static points (``cfg``: other weights than the run's)."""
        fit_static_points(tracks, self.uv, self.D, vis, xyz, self.K, self.R, self.t, cfg or self.cfg, self.device,
                          iters)

    def refit(self, tracks, vis, xyz, lambda_dc: float, iters: int) -> None:
        """:meth:`fit` with the depth term weighed ``lambda_dc``."""
        self.fit(tracks, vis, xyz, replace(self.cfg, lambda_dc=lambda_dc), iters)


def classify_masked(labels, vis, qf, fits: StaticFits, dynamic, xyz, info: dict, offsets: bool = True,
                    core: np.ndarray | None = None) -> np.ndarray:
    """The tracks the masks call dynamic or ambiguous (``labels [N]``, seen twice or more) get the as-static test
    with the poses held: the coarse masks are dilated, and a track that fits one static point is static (inside
    the sure-dynamic region only when the fit also holds within ``mask_dynamic_px``); one that fails and slips off
    a point it held is that point over its run (``optim.slip``). ``offsets`` False (w/o O_static): no test.
    ``core [N]`` bool: the tracks deep inside the masks (``mask_core_px``), left dynamic untested."""
    cfg = fits.cfg
    cand = (labels != STATIC) & (vis.sum(1) >= 2)
    if core is not None:
        cand &= ~core
    cand = np.flatnonzero(cand)
    if not (offsets and len(cand)):
        return vis
    # in float32 whatever cfg.dtype: a threshold test at epsilon = 0.1 m needs no more, and it halves the
    # memory traffic of the largest step at 120 frames (2.3M observations: 6.5 -> 3.6 s, the same
    # decision for all 72,464 tracks, points within 0.11 mm of float64's)
    still, Xc, worst = fits.test(cand, vis)
    if cfg.mask_dynamic_px > 0:  # inside the sure-dynamic region the fit must hold in pixels too
        still &= (labels[cand] != DYNAMIC) | (worst <= cfg.mask_dynamic_px)
    # (not in the paper) a failed track that holds a static point around its query frame and then
    # slips off it is that static point, seen in the run only (optim.slip)
    px = np.full(len(cand), cfg.slip_px)
    if cfg.mask_dynamic_px > 0:
        px[labels[cand] == DYNAMIC] = min(cfg.slip_px, cfg.mask_dynamic_px)
    vis, slipped = fits.rescue(cand, still, Xc, px, vis, qf)
    fixed = cand[still]
    dynamic[fixed] = False
    dynamic[cand[~still]] = True
    xyz[fixed] = Xc[still][:, None]
    info["classify"] = {"tested": int(len(cand)), "static": int(still.sum()), "slipped": slipped,
                        "core": 0 if core is None else int(core.sum())}
    return vis


def rebuild_static(labels, s2, ok_s2, moving_s2, vis, qf, D, poses, fits: StaticFits, dynamic, xyz, info: dict,
                   offsets: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Every static track outside stage 2's subset ``s2`` (``ok_s2`` its static part, ``moving_s2 [len(s2)]`` its
    movers) and, with ``own_test``, every track seen once: its own ray at the query frame, depth from the
    propagated scale of the optimised static points visible there (the appendix's speed-up), or (``static_rebuild
    fit``) triangulated with the poses held. Those the optimised neighbours' vote calls moving are moving (the
    appendix), or with ``own_test`` only if their own as-static test fails too and they hold no run (a neighbour
    that slipped onto a mover does not take its neighbours with it). Returns (visibility, the tracks seen once,
    left to :func:`vote_short_tracks`)."""
    cfg, K, uv = fits.cfg, fits.K, fits.uv
    own = cfg.own_test  # (not in the paper) the static tracks' own observations have a say
    single = vis.sum(1) < 2
    rest = np.setdiff1d(np.flatnonzero(labels == STATIC), s2)
    rest = np.union1d(rest, np.flatnonzero((labels != STATIC) & single) if own else
                      np.flatnonzero((labels == AMBIGUOUS) & single))
    ref_ratio = camera_depths(xyz[ok_s2], poses) / np.maximum(D[ok_s2], 1e-6)
    moving_flag = moving_s2.astype(np.float64)
    multi_rest = rest[~single[rest]]
    once = rest[single[rest]] if own else rest[:0]  # voted on after the depth-mover test (vote_short_tracks)
    fit = multi_rest if cfg.static_rebuild == "fit" else rest[:0]
    placed = np.ones(len(vis), bool)  # the tracks that get their position here (the others are fitted below)
    placed[fit] = False
    voted = np.zeros(len(vis), bool)  # moving by the vote of the optimised neighbours (the appendix)
    vis_s2 = np.ascontiguousarray(vis[s2].T)
    for q in np.unique(qf[rest]):
        who_all = rest[qf[rest] == q]
        who = who_all[placed[who_all]]
        v = np.flatnonzero(vis_s2[q])
        refs = s2[v]
        if len(refs):
            mv = propagate_ratio(uv[refs, q], D[refs, q], moving_flag[v], uv[who_all, q], D[who_all, q], K, cfg.idw_k)
            voted[who_all[mv >= 0.5]] = True
        if not len(who):
            continue
        r_ok = ~moving_s2[v]
        if r_ok.sum() == 0:
            ratio = np.full(len(who), np.nanmedian(ref_ratio) if ref_ratio.size else 1.0)
        else:
            vv = v[r_ok]
            ratio = propagate_ratio(uv[s2[vv], q], D[s2[vv], q], ref_ratio[np.searchsorted(ok_s2, s2[vv]), q],
                                    uv[who, q], D[who, q], K, cfg.idw_k)
        pts = unproject(uv[who, q], ratio * D[who, q], K)
        xyz[who] = transform(poses[q], pts)[:, None]
    if not own:
        dynamic[voted] = True
    else:
        suspects = multi_rest[voted[multi_rest]]
        if offsets and len(suspects):
            still, Xv, _ = fits.test(suspects, vis)
            # ... and one that fails it holds its point and then slips, like the masks' tracks
            # (not in the paper; 2 px, slip_px; the fits below then see its run only)
            vis, slipped = fits.rescue(suspects, still, Xv, np.full(len(suspects), cfg.slip_px), vis, qf)
            dynamic[suspects[~still]] = True
            info["vote_tested"] = {"tested": int(len(suspects)), "static": int(still.sum()), "slipped": slipped}
        else:
            dynamic[suspects] = True
    if len(fit):  # triangulated with the poses held
        fits.fit(fit, vis, xyz)
        info["static_fitted"] = int(len(fit))
    info["dynamic"] = int(dynamic.sum())
    return vis, once


def vote_short_tracks(once, queries, vis, D, fits: StaticFits, dynamic, xyz, colours, info: dict,
                      shape: tuple[int, int], core: np.ndarray | None = None) -> None:
    """(not in the paper) A track seen once cannot be tested, and one seen in ``vote_short`` frames or fewer
    cannot fail the test: each takes the verdict of the tracks seen in more frames nearest it (one per query frame
    and VOTE_CELL_PX square, prior-lifted 3D distance and ``colours [N,3]`` at the query pixels), the depth-mover
    test's included, and becomes dynamic only where its own static fit misses a pixel by more than
    ``vote_flip_px``. A track seen once with none of those voters visible within ``vote_once_gap_px`` of it in
    its query frame takes instead, after the others are settled, the vote of every track seen in two frames or
    more (one per query frame and VOTE_CELL_PX square): at an image border the camera leaves, the nearest long
    tracks to a strip seen once may all lie on a mover beside it, beyond the short static ones. ``once``: the
    tracks seen once that :func:`rebuild_static` placed; ``queries [N,3]``; ``shape`` (H, W) of the frames.
    ``core [N]`` bool: the tracks deep inside the masks (``mask_core_px``), whose dynamic label stands here as in
    :func:`classify_masked`: they vote but are not voted on. Without that, a masked mover seen in ``vote_short``
    frames or fewer (one that enters late or leaves early, or any mover of a video of about that length) had only
    the background's long tracks for voters and was voted static whole."""
    cfg, K, uv = fits.cfg, fits.K, fits.uv
    qf = queries[:, 0].astype(np.int64)
    seen = vis.sum(1)
    voters = np.flatnonzero(seen > cfg.vote_short)
    voters = voters[cell_representatives(queries[voters], VOTE_CELL_PX)]
    short_multi = np.flatnonzero((seen >= 2) & (seen <= cfg.vote_short))
    if core is not None:  # the masks' cores keep their label
        once, short_multi = once[~core[once]], short_multi[~core[short_multi]]
    far = far_from(once, voters, uv, vis, qf, cfg.vote_once_gap_px, shape)
    first, later = once[~far], once[far]  # the tracks seen once voted with the short ones / after them
    short = np.union1d(first, short_multi)
    colour = colours is not None and cfg.vote_colour_sigma > 0
    k = cfg.vote_k if colour else cfg.idw_k
    was = dynamic.copy()  # the verdicts before the vote

    @cache  # asked for by the bare frames' vote and the late one: made once
    def tested_voters():  # the tracks seen in two frames or more, one per query frame and VOTE_CELL_PX square
        multi = np.flatnonzero(seen >= 2)
        return multi[cell_representatives(queries[multi], VOTE_CELL_PX)]

    if len(short):
        dynamic[short] = vote_short(short, voters, dynamic, uv, D, vis, qf, K, k, colours, cfg.vote_colour_sigma)
        # in a frame that no track seen in more than vote_short frames reaches (a video hardly longer), the
        # tracks seen once take the vote of those seen in two or more, as with vote_short 1
        bare = first[~vis[voters].any(0)[qf[first]]] if len(voters) else first
        if len(bare):
            dynamic[bare] = vote_short(bare, tested_voters(), dynamic, uv, D, vis, qf, K, k, colours,
                                       cfg.vote_colour_sigma)
        # ... made dynamic only when its own static fit misses a pixel by more than vote_flip_px
        tested = seen[short] >= 2  # a track seen once has no fit; its point is the rebuild's
        flip = short[dynamic[short] & ~was[short] & tested]
        if len(flip) and cfg.vote_flip_px > 0:
            worst = fits.test(flip, vis)[2]
            dynamic[flip[worst <= cfg.vote_flip_px]] = False
        # tracks the vote made static get their static point now: the off-point observations are judged
        # against it next
        now_static = short[~dynamic[short] & was[short] & tested]
        if len(now_static):
            fits.fit(now_static, vis, xyz)
    if len(later):
        dynamic[later] = vote_short(later, tested_voters(), dynamic, uv, D, vis, qf, K, k, colours,
                                    cfg.vote_colour_sigma)
    if len(short) or len(later):
        info["voted"] = {"tracks": int(len(short) + len(later)), "changed": int((dynamic != was).sum())}
    info["dynamic"] = int(dynamic.sum())


def far_from(who, refs, uv, vis, qf, px: float, shape: tuple[int, int]) -> np.ndarray:
    """``[n]`` bool: of the tracks ``who`` [n] (indices), those with no track of ``refs`` (indices) visible in their
    query frame within ``px`` pixels of their query pixel, positions rounded to their pixel (a distance transform
    of each such frame's ``shape`` (H, W) image of the refs' pixels, 5x5 mask: a k-d tree over the refs of every
    frame cost 3.5 s of a 120-frame run). uv [N,T,2] px, vis [N,T], qf [N] query frames."""
    out = np.zeros(len(who), bool)
    if not np.isfinite(px) or not len(who):
        return out
    H, W = shape
    refs_t = np.ascontiguousarray(vis[refs].T)
    for q in np.unique(qf[who]):
        sel = np.flatnonzero(qf[who] == q)
        r = refs[refs_t[q]]
        if not len(r):
            out[sel] = True
            continue
        x, y = nearest_pixel(uv[r, q], W, H)
        free = np.full((H, W), 255, np.uint8)
        free[y, x] = 0
        dist = cv2.distanceTransform(free, cv2.DIST_L2, cv2.DIST_MASK_5)
        qx, qy = nearest_pixel(uv[who[sel], q], W, H)
        out[sel] = dist[qy, qx] > px
    return out


def drop_off_point(vis, qf, fits: StaticFits, dynamic, xyz, info: dict) -> np.ndarray:
    """(not in the paper) A static track's observations off its point by epsilon or more are not of its point
    (its 2D track slipped onto an occluder, or was found again off the point after a gap): returned as not
    visible, so that the refit and the video depth leave them out (query frames kept). A new visibility."""
    still = np.flatnonzero(~dynamic & (vis.sum(1) >= 2))
    off = static_outliers(still, fits.uv, fits.D, vis, xyz, fits.K, fits.R, fits.t, fits.cfg, fits.device)
    off[np.arange(len(still)), qf[still]] = False
    vis = vis.copy()
    vis[still] &= ~off
    info["static_outliers"] = int(off.sum())
    return vis


def photo_rescue(uv, vis, qf, D, poses, K, frames, masks, cfg: OptimConfig, dynamic, xyz, info: dict,
                 labels: np.ndarray | None = None,
                 depth: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(not in the paper) Every dynamic track (with ``labels [N]``: of those the masks did not call static) whose
    static hypothesis holds in the images (``optim.photo_static``,
    the depth ``D [N,T]`` at its query frame, ``frames [T,h,w,3]`` uint8, ``masks [T,h,w]``; with the consistent
    video depth ``depth [T,h,w]`` metres and ``cfg.photo_static_hidden``, the frames where a nearer surface hides
    the point are not tested) becomes that static
    point: ``dynamic`` and ``xyz`` updated in place, its 2D track the point's projection and its visibility the
    frames that matched. Returns (uv, vis, the tracks changed); uv and vis are copies when any changed."""
    # the masks' static region is left out: there a mover the masks missed, sliding slowly over a smooth texture,
    # shows colours near its query colour at the static projection too (twenty scenes: bg-mover recall 93.6 -> 91.0
    # with every dynamic track tested, `default` 10 97.9 -> 79.3; docs/lifting.md)
    if cfg.photo_static_grey <= 0:
        return uv, vis, np.zeros(0, np.int64)
    cand = np.flatnonzero(dynamic if labels is None else dynamic & (labels != STATIC))
    if labels is not None and cfg.photo_static_near_px > 0:  # ... but for those a masked mover passed
        region = np.flatnonzero(dynamic & (labels == STATIC))
        cand = np.union1d(cand, region[near_masks(uv[region], vis[region], masks, cfg.photo_static_near_px)])
    if not len(cand):
        return uv, vis, cand
    static, X, pix, seen = static_hypothesis(uv[cand, qf[cand]], D[cand, qf[cand]].astype(np.float64), qf[cand],
                                             poses, K, blurred_frames(frames), mask_regions(masks, MASK_MARGIN_PX)[0],
                                             cfg.photo_static_grey, cfg.photo_static_frac, cfg.photo_static_frames,
                                             depth_scales(cfg.photo_static_range),
                                             depth if cfg.photo_static_hidden else None, cfg.occluded_static_depth,
                                             cfg.photo_static_patch,
                                             (uv[cand], vis[cand], cfg.photo_static_track_px)
                                             if cfg.photo_static_track_px > 0 else None)
    return become_static(uv, vis, cand, static, X, pix, seen, dynamic, xyz, info, "photo_static")


def query_depths(depth: np.ndarray, uv: np.ndarray, qf: np.ndarray, cand: np.ndarray) -> np.ndarray:
    """``[n]`` float64 metres: the video depth ``depth [T,h,w]`` at the query pixels (nearest) of the tracks
    ``cand [n]`` (``uv [N,T,2]`` px, query frames ``qf [N]``)."""
    H, W = depth.shape[1:]
    x, y = nearest_pixel(uv[cand, qf[cand]], W, H)
    return depth[qf[cand], y, x].astype(np.float64)


def occlusion_rescue(uv, vis, qf, depth, poses, K, cfg: OptimConfig, dynamic, xyz,
                     info: dict, in_place: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(not in the paper) Every dynamic track that is its query pixel's static point wherever that point is in view,
    and strayed where a nearer surface hid it (``optim.occluded_static``; the consistent video depth ``depth
    [T,h,w]`` metres gives the query pixels' depths and what hides them), becomes that static point: ``dynamic``
    and ``xyz`` updated in place, its 2D track the point's projection and its visibility the query frame and the
    in-view frames where it was on the point. Returns (uv, vis, the tracks changed); copies when any changed
    (``in_place``: uv and vis, the caller's own copies, written in place)."""
    cand = np.flatnonzero(dynamic)
    if cfg.occluded_static_frames <= 0 or not len(cand):
        return uv, vis, np.zeros(0, np.int64)
    static, X, pix, seen = static_behind_occluders(uv[cand], vis[cand], qf[cand], query_depths(depth, uv, qf, cand),
                                                   poses, K,
                                                   depth, cfg.occluded_static_px, cfg.occluded_static_frac,
                                                   min_frames=cfg.occluded_static_in_view,
                                                   min_hidden=cfg.occluded_static_frames,
                                                   in_front=cfg.occluded_static_depth)
    return become_static(uv, vis, cand, static, X, pix, seen, dynamic, xyz, info, "occluded_static", in_place)


PHOTO_MOVING_FRAMES = 6  # the photometric mover test needs at least this many tested frames (3: more static tracks
# flagged for the same movers; stop 49's probe, docs/lifting.md)
# ... and leaves out the tracks queried this close to the image's edge (px), where the query colour is read from a blur
# that reaches past the edge and the point soon leaves the view: on `default` seed 13, 92 of the test's 143 false
# alarms, and none of the missed movers it found on `default` 0 / 11 / 12 (56 of 280 on `hard` 3)
PHOTO_MOVING_EDGE_PX = 2.0


def photo_moving(uv, vis, qf, depth, poses, K, frames, masks, cfg: OptimConfig, dynamic, labels,
                 info: dict) -> np.ndarray:
    """(not in the paper; on by default since stop 52, ``--photo-moving 0`` turns it off) The reverse of
    :func:`photo_rescue`, for movers the masks missed: every static-labelled track of the masks' static region seen
    in at most ``cfg.vote_short`` frames, queried more than PHOTO_MOVING_EDGE_PX from the image's edge, whose query
    pixel's static point (the video depth ``depth [T,h,w]`` there, times 0.96-1.04) shows its query colour in less
    than ``cfg.photo_moving_share`` of at least PHOTO_MOVING_FRAMES frames where the point is outside the masks and
    not hidden becomes dynamic (``dynamic`` updated in place). Its positions stay its static point's: this runs
    after stage 3, since it reads the video depth. Returns the tracks changed."""
    if cfg.photo_moving_share <= 0:
        return np.zeros(0, np.int64)
    cand = np.flatnonzero(~dynamic & (labels == STATIC) & (vis.sum(1) <= cfg.vote_short))
    H, W = depth.shape[1:]
    q_uv = uv[cand, qf[cand]]
    inner = ((q_uv[:, 0] > PHOTO_MOVING_EDGE_PX) & (q_uv[:, 0] < W - 1 - PHOTO_MOVING_EDGE_PX)
             & (q_uv[:, 1] > PHOTO_MOVING_EDGE_PX) & (q_uv[:, 1] < H - 1 - PHOTO_MOVING_EDGE_PX))
    cand, q_uv = cand[inner], q_uv[inner]
    if not len(cand):
        return cand
    share, count, _, _ = colour_shares(q_uv, query_depths(depth, uv, qf, cand), qf[cand], poses,
                                       K, blurred_frames(frames), mask_regions(masks, MASK_MARGIN_PX)[0],
                                       cfg.photo_static_grey, depth_scales(cfg.photo_static_range), depth,
                                       cfg.occluded_static_depth)
    idx = cand[(count >= PHOTO_MOVING_FRAMES) & (share < cfg.photo_moving_share)]
    dynamic[idx] = True
    info["photo_moving"] = {"tested": int(len(cand)), "dynamic": int(len(idx))}
    info["dynamic"] = int(dynamic.sum())
    return idx


def become_static(uv, vis, cand, static, X, pix, seen, dynamic, xyz, info: dict,
                  name: str, in_place: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The candidates ``cand [n]`` that a test found ``static [n]`` become their points ``X [n,3]`` (world metres):
    ``dynamic`` and ``xyz`` updated in place, their 2D tracks ``pix [m,T,2]`` and visibility ``seen [m,T]``;
    ``info[name]`` counts them. Returns (uv, vis, the tracks changed); copies when any changed, unless
    ``in_place`` (then uv and vis themselves, written: one ``[N,T,2]`` array fewer on a long video)."""
    idx = cand[static]
    info[name] = {"tested": int(len(cand)), "static": int(len(idx))}
    if not len(idx):
        return uv, vis, idx
    if not in_place:
        uv, vis = uv.copy(), vis.copy()
    uv[idx], vis[idx] = pix, seen
    dynamic[idx] = False
    xyz[idx] = X[static][:, None].astype(xyz.dtype)
    info["dynamic"] = int(dynamic.sum())
    return uv, vis, idx
