"""Weight-free depth: structure from motion on the static dense tracks, densified to every pixel.

Incremental SfM, written on OpenCV's geometric solvers (no SfM library on PyPI takes tracks as input; COLMAP's
Python bindings match features themselves):

1. the starting pair is the pair of frames with the most parallax a homography cannot explain (a rotating
   camera has none), among pairs sharing enough tracks;
2. essential matrix (RANSAC) and pose recovery, triangulation of the shared tracks;
3. every other frame, outwards from the pair, by PnP-RANSAC on the tracks already triangulated, each
   registration followed by triangulation of the tracks it makes possible (linear, all registered views);
4. bundle adjustment of all poses and points with the stage-2 solver (Huber kernel, Schur complement, no
   depth prior);
5. all static dense tracks triangulated with the final poses; per frame, their depths (weighted by the
   triangulation angle) are spread to every pixel by push-pull in log depth. A dynamic region (a connected
   component of the masks) cannot be triangulated: each of its columns takes the depth of the static pixels just
   below it in that column (where an object stands on the ground, its contact; ``fill_dynamic``), a column with
   nothing below the nearest column's, and a region with no ground below it the median of its border.

The scale is arbitrary (the median depth is set to 1). When the camera hardly moves (no parallax), depth
cannot be recovered from the video: a constant depth is returned with a message saying so. So it is for a fixed
camera (a tripod), whose tracks' drift reads as parallax: where the static tracks of the starting pair move about
as much as their parallax and no essential matrix explains it (:mod:`trackingworld.priors.drift`).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field

import cv2
import numpy as np
import torch

from trackingworld.config import SFM_CONTACTS, OptimConfig
from trackingworld.geometry import focal_length, invert_pose, pose_from_rt, project, transform, unproject
from trackingworld.optim import stage2
from trackingworld.optim.densify import cell_representatives
from trackingworld.priors.drift import FIXED_EPIPOLAR, FIXED_MOTION, looks_fixed, sampson_px, transfer_px
from trackingworld.priors.fill import densify
from trackingworld.tracking2d.base import TrackResult


@dataclass
class SfMConfig:
    cell: int = 8  # one track per (query frame, cell) takes part in the incremental reconstruction
    max_points: int = 6000
    min_parallax_px: float = 2.0  # median residual parallax (after a homography) of the best pair, else "static"
    # a pair whose tracks move less than fixed_motion x its parallax and whose essential matrix leaves more than
    # fixed_epipolar x it is a fixed camera's drift (priors.drift), "static" too
    fixed_motion: float = FIXED_MOTION
    fixed_epipolar: float = FIXED_EPIPOLAR
    min_shared: int = 60
    reproj_px: float = 2.0  # inlier threshold of RANSAC, PnP and triangulation
    min_angle_deg: float = 1.0  # rays of a triangulated point must span this angle
    ba_iters: int = 15
    # how a dynamic region takes its depth: "column" (each column the ground just below it, fill_dynamic) or
    # "region" (one value per region, fill_region: the rule before stop 78)
    contact: str = "column"
    verbose: bool = True


@dataclass
class SfMResult:
    depth: np.ndarray  # [T,H,W] float32, median 1 (arbitrary scale)
    poses_c2w: np.ndarray  # [T,4,4]
    ok: bool  # False: no parallax (or SfM failed: info["failed"] says why), depth is constant
    message: str
    info: dict = field(default_factory=dict)


def _log(cfg: SfMConfig, msg: str) -> None:
    if cfg.verbose:
        print(f"[sfm] {msg}", file=sys.stderr, flush=True)


def residual_parallax(pa: np.ndarray, pb: np.ndarray) -> float:
    """Median distance (px) between ``pb`` and ``pa`` mapped by the best homography: the parallax left once a
    rotation (or a plane) is explained."""
    try:
        Hm, _ = cv2.findHomography(pa.astype(np.float64), pb.astype(np.float64), cv2.LMEDS)
    except cv2.error:
        Hm = None
    if Hm is None:
        return 0.0
    return float(np.median(transfer_px(pa, pb, Hm)))


def choose_pair(uv: np.ndarray, vis: np.ndarray, cfg: SfMConfig) -> tuple[int, int, float]:
    """The starting pair (a, b) and its residual parallax (px)."""
    T = vis.shape[1]
    best = (0, T - 1, 0.0)
    starts = np.unique(np.linspace(0, T - 2, min(T - 1, 6)).round().astype(int))
    for a in starts:
        counts = (vis[:, a:a + 1] & vis).sum(0)
        for b in range(a + 1, T):
            if counts[b] < max(cfg.min_shared, 0.3 * counts[a]):
                continue
            both = vis[:, a] & vis[:, b]
            par = residual_parallax(uv[both, a], uv[both, b])
            if par > best[2]:
                best = (int(a), int(b), par)
    return best


def triangulate(uv: np.ndarray, vis: np.ndarray, R: np.ndarray, t: np.ndarray, K: np.ndarray,
                chunk: int = 50000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Linear triangulation of every track over its visible frames.

    uv [N,T,2] px, vis [N,T] (only registered frames), world-to-camera R [T,3,3], t [T,3]. Returns points
    [N,3] world, the largest reprojection error [N] px and the largest angle between two of its rays [N] deg.
    Tracks seen in fewer than two frames get NaN.
    """
    N, T = vis.shape
    w2c = pose_from_rt(R, t)  # [T,4,4]
    P = w2c[:, :3]  # [T,3,4]
    centres = invert_pose(w2c)[:, :3, 3]  # [T,3]
    X = np.full((N, 3), np.nan)
    err = np.full(N, np.inf)
    ang = np.zeros(N)
    for s in range(0, N, chunk):
        sl = slice(s, min(N, s + chunk))
        u, v = uv[sl].astype(np.float64), vis[sl]
        xn = unproject(u, np.ones(u.shape[:-1]), K)  # normalised image coordinates [n,T,3]
        a = xn[..., 0:1] * P[None, :, 2] - P[None, :, 0]  # [n,T,4]
        b = xn[..., 1:2] * P[None, :, 2] - P[None, :, 1]
        w = v[..., None].astype(np.float64)
        A = np.einsum("nti,ntj->nij", a * w, a) + np.einsum("nti,ntj->nij", b * w, b)
        ok = v.sum(1) >= 2
        _, vecs = np.linalg.eigh(A[ok])
        h = vecs[:, :, 0]
        Xs = h[:, :3] / np.where(np.abs(h[:, 3:]) > 1e-12, h[:, 3:], 1e-12)
        idx = np.flatnonzero(ok)
        pix, z = project(transform(w2c[None], Xs[:, None]), K, eps=1e-9)
        e = np.where(v[idx] & (z > 1e-6), np.linalg.norm(pix - u[idx], axis=-1), 0.0)
        e = np.where(v[idx] & (z <= 1e-6), np.inf, e)
        rays = Xs[:, None] - centres[None]
        rays /= np.linalg.norm(rays, axis=-1, keepdims=True) + 1e-12
        rays = np.where(v[idx][..., None], rays, np.nan)
        mean = np.nanmean(rays, 1)  # angle to the mean ray: half the spread, a cheap lower bound of the max
        cosang = np.einsum("nti,ni->nt", rays, mean / (np.linalg.norm(mean, axis=-1, keepdims=True) + 1e-12))
        ang_s = 2 * np.degrees(np.arccos(np.clip(np.nanmin(cosang, 1), -1, 1)))
        X[s + idx] = Xs
        err[s + idx] = e.max(1)
        ang[s + idx] = ang_s
    return X, err, ang


def _camera_depths(R: np.ndarray, t: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Depth ``[N,T]`` of world points ``X [N,3]`` in the cameras (world-to-camera ``R [T,3,3]``, ``t [T,3]``)."""
    return transform(pose_from_rt(R, t)[None], X[:, None])[..., 2]


def _nearest(reg: np.ndarray, f: int) -> int:
    """The registered frame closest to frame ``f``."""
    near = np.flatnonzero(reg)
    return int(near[np.argmin(np.abs(near - f))])


def _register(X: np.ndarray, has3d: np.ndarray, uv_f: np.ndarray, vis_f: np.ndarray, K: np.ndarray,
              cfg: SfMConfig, guess: tuple[np.ndarray, np.ndarray] | None):
    """PnP-RANSAC of one frame: world-to-camera (R [3,3], t [3]) or None."""
    sel = np.flatnonzero(has3d & vis_f)
    if len(sel) < 12:
        return None
    obj, img = X[sel].astype(np.float64), uv_f[sel].astype(np.float64)
    use_guess = guess is not None
    rvec = cv2.Rodrigues(guess[0])[0] if use_guess else None
    tvec = guess[1].reshape(3, 1).copy() if use_guess else None
    try:
        ok, rvec, tvec, inl = cv2.solvePnPRansac(obj, img, K, None, rvec, tvec, useExtrinsicGuess=use_guess,
                                                 iterationsCount=200, reprojectionError=cfg.reproj_px,
                                                 confidence=0.999, flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok or inl is None or len(inl) < max(12, 0.25 * len(sel)):
            return None
        inl = inl.ravel()
        rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], K, None, rvec, tvec)
    except cv2.error:
        return None
    return cv2.Rodrigues(rvec)[0], tvec.ravel()


def _order(a: int, b: int, T: int) -> list[int]:
    """Frames to register after the pair: between them from both ends inwards, then outwards."""
    inner = [f for f in range(a + 1, b)]
    inner = sorted(inner, key=lambda f: min(f - a, b - f))
    outer = [f for k in range(1, T) for f in (b + k, a - k) if 0 <= f < T and not (a <= f <= b)]
    return inner + outer


def _bundle_adjust(R, t, X, uv, vis, K, ref: int, cfg: SfMConfig, device="cpu"):
    """Huber bundle adjustment (stage-2 solver without a depth prior); frame ``ref`` fixed."""
    T = vis.shape[1]
    order = [ref] + [f for f in range(T) if f != ref]  # the solver keeps its frame 0 fixed
    z = _camera_depths(R, t, X)
    med_z = float(np.median(z[vis]))
    f = focal_length(K)
    # lambda_asap so that the eliminated offsets make a Huber kernel of threshold reproj_px at the median depth
    ocfg = OptimConfig(lambda_dc=0.0, lambda_asap=2 * cfg.reproj_px * f / med_z, no_depth_consistency=True)
    p = stage2.BAProblem.from_tracks(uv[:, order], z[:, order], vis[:, order], K, ocfg, torch.float64, device)
    Rt = torch.as_tensor(R[order], dtype=torch.float64, device=device)
    tt = torch.as_tensor(t[order], dtype=torch.float64, device=device)
    Xt = torch.as_tensor(X, dtype=torch.float64, device=device)
    c0 = float(stage2.loss(Rt, tt, Xt, p))
    sol = stage2.solve_lm(Rt, tt, Xt, p, cfg.ba_iters, 1e-6)
    Rt, tt, Xt, c1 = sol.R, sol.t, sol.X, sol.cost
    inv = np.argsort(order)
    return Rt.cpu().numpy()[inv], tt.cpu().numpy()[inv], Xt.cpu().numpy(), (c0, c1)


def reconstruct(tr: TrackResult, static: np.ndarray, K: np.ndarray, cfg: SfMConfig):
    """Incremental SfM on the static tracks (``static [N]`` bool). Returns ((R [T,3,3], t [T,3] world-to-camera,
    NaN for frames that could not be registered; reg [T] bool, the registered frames), info), or (None, info)
    when it cannot start (too little parallax, a fixed camera's drift, no essential matrix) or too few points
    survive."""
    uv, vis = tr.tracks, tr.visible
    T = vis.shape[1]
    idx = np.flatnonzero(static & (vis.sum(1) >= 2))
    idx = idx[cell_representatives(tr.queries[idx], cfg.cell)]
    if len(idx) > cfg.max_points:  # keep the longest tracks
        idx = np.sort(idx[np.argsort(-vis[idx].sum(1), kind="stable")[:cfg.max_points]])
    u, v = uv[idx].astype(np.float64), vis[idx]
    a, b, par = choose_pair(u, v, cfg)
    both = np.flatnonzero(v[:, a] & v[:, b])
    info = {"pair": [a, b], "parallax_px": par, "points": int(len(idx))}
    if len(both) < cfg.min_shared:  # no pair of frames shares enough static tracks (choose_pair found none)
        info["failed"] = f"only {len(idx)} static tracks, {len(both)} of them seen in both frames {a} and {b}"
        return None, info
    if par < cfg.min_parallax_px:
        return None, info
    try:
        E, m = cv2.findEssentialMat(u[both, a], u[both, b], K, cv2.RANSAC, 0.999, cfg.reproj_px)
    except cv2.error:
        E = None
    if E is None:
        info["failed"] = f"no essential matrix fits frames {a} and {b}"
        return None, info
    E = E[:3]
    info["motion_px"] = float(np.median(np.linalg.norm(u[both, b] - u[both, a], axis=1)))
    Ki = np.linalg.inv(K)
    info["epipolar_px"] = float(np.median(sampson_px(Ki.T @ E @ Ki, u[both, a], u[both, b])))
    if looks_fixed(info["motion_px"], par, info["epipolar_px"], cfg.fixed_motion, cfg.fixed_epipolar):
        info["fixed"] = True  # the parallax is a fixed camera's drift
        return None, info
    _, Rb, tb, _ = cv2.recoverPose(E, u[both, a], u[both, b], K, mask=m)
    R = np.full((T, 3, 3), np.nan)
    t = np.full((T, 3), np.nan)
    R[a], t[a] = np.eye(3), np.zeros(3)
    R[b], t[b] = Rb, tb.ravel()
    reg = np.zeros(T, bool)
    reg[[a, b]] = True
    X = np.full((len(idx), 3), np.nan)
    has3d = np.zeros(len(idx), bool)

    def retriangulate():
        Xn, err, ang = triangulate(u, v & reg[None], np.nan_to_num(R), np.nan_to_num(t), K)
        good = (err < cfg.reproj_px * 2) & (ang >= cfg.min_angle_deg)
        X[:] = np.where(good[:, None], Xn, np.nan)
        has3d[:] = good

    retriangulate()
    for f in _order(a, b, T):
        g = _nearest(reg, f)
        pose = _register(X, has3d, u[:, f], v[:, f], K, cfg, (R[g], t[g]))
        if pose is None:
            continue
        R[f], t[f] = pose
        reg[f] = True
        retriangulate()
    info["registered"] = int(reg.sum())
    if has3d.sum() < 30:
        info["failed"] = f"only {int(has3d.sum())} static tracks triangulated over {int(reg.sum())} frames (need 30)"
        return None, info
    Rr, tr_, _, costs = _bundle_adjust(R[reg], t[reg], X[has3d], u[has3d][:, reg], v[has3d][:, reg], K,
                                       int(np.flatnonzero(np.flatnonzero(reg) == a)[0]), cfg)
    R[reg], t[reg] = Rr, tr_
    info["ba_loss"] = costs
    return (R, t, reg), info


def _fill_poses(R: np.ndarray, t: np.ndarray, reg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unregistered frames take the pose of the nearest registered one."""
    R, t = R.copy(), t.copy()
    for f in np.flatnonzero(~reg):
        g = _nearest(reg, f)
        R[f], t[f] = R[g], t[g]
    return R, t


def fill_region(depth: np.ndarray, mask: np.ndarray, ring_px: int = 6) -> np.ndarray:
    """Give each connected region of ``mask [H,W]`` one value: the median of ``depth [H,W]`` over the static
    ring pixels below the region's centre row, or over the whole ring (the rule before stop 78, and the fallback of
    :func:`fill_dynamic` for a region with no ground below it)."""
    out = depth.copy()
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ring_px + 1,) * 2)
    rows = np.arange(mask.shape[0])[:, None]
    for i in range(1, n):
        x, y, w, h = stats[i, :4]
        pad = 2 * ring_px
        y0, y1 = max(0, y - pad), min(mask.shape[0], y + h + pad)
        x0, x1 = max(0, x - pad), min(mask.shape[1], x + w + pad)
        reg = lab[y0:y1, x0:x1] == i
        ring = (cv2.dilate(reg.astype(np.uint8), k) > 0) & ~mask[y0:y1, x0:x1]
        below = ring & (rows[y0:y1] >= y + 0.75 * h)
        vals = depth[y0:y1, x0:x1][below if below.sum() >= 5 else ring]
        if len(vals):
            out[y0:y1, x0:x1][reg] = np.median(vals)
    return out


def fill_dynamic(depth: np.ndarray, mask: np.ndarray, ring_px: int = 6, min_columns: int = 3,
                 smooth_columns: int = 5) -> np.ndarray:
    """Fill the dynamic regions of ``depth [H,W]`` (log depth, or any value that is constant up a vertical face)
    column by column from the ground they stand on: in each image column of a connected region of ``mask [H,W]``,
    every region pixel takes the median of the static pixels within ``ring_px`` below the region's lowest pixel
    in that column (where the object meets the floor; y is down). The column values are median-smoothed over
    ``smooth_columns`` columns; a column with no static pixel below it (the region reaches the image's bottom, or
    another mask lies below) takes the nearest column's that has one. A region with fewer than ``min_columns``
    such columns takes :func:`fill_region`'s one value.

    A region holds one object or several that touch in the image, at other depths, and an object cut by the image's
    bottom edge meets the ground only beside it: one value per column follows both, where one per region (the rule
    before) puts two objects at one depth. On synthetic scenes whose movers stand on the floor
    (``SceneConfig.grounded_movers``) with the ground-truth depth as the static depth, the masked movers' median
    absolute log-depth error went 0.118 -> 0.085; in the pipeline, ``docs/priors.md`` (stop 78)."""
    out = depth.copy()
    H = mask.shape[0]
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    half = smooth_columns // 2
    fallback = None
    for i in range(1, n):
        x, y, w, h = stats[i, :4]
        reg = lab[:, x:x + w] == i
        low = H - 1 - np.argmax(reg[::-1], axis=0)  # [w] the region's lowest row in each column
        vals = np.full(w, np.nan)
        for c in np.flatnonzero(reg.any(0) & (low + 1 < H)):
            rows = np.arange(low[c] + 1, min(H, low[c] + 1 + ring_px))
            rows = rows[~mask[rows, x + c]]
            if len(rows):
                vals[c] = np.median(depth[rows, x + c])
        have = np.flatnonzero(np.isfinite(vals))
        if len(have) < min_columns:
            fallback = fill_region(depth, mask, ring_px) if fallback is None else fallback
            out[:, x:x + w][reg] = fallback[:, x:x + w][reg]
            continue
        smooth = np.array([np.nanmedian(vals[max(0, c - half):c + half + 1]) for c in have])
        nearest = np.abs(np.arange(w)[:, None] - have[None]).argmin(1)  # [w] index into have
        rr, cc = np.nonzero(reg)
        out[rr, x + cc] = smooth[nearest[cc]]
    return out


CONTACT_RULES = dict(zip(SFM_CONTACTS, (fill_dynamic, fill_region), strict=True))


def sfm_depth(tr: TrackResult, static: np.ndarray, K: np.ndarray, masks: np.ndarray,
              cfg: SfMConfig | None = None) -> SfMResult:
    """Depth maps ``[T,H,W]`` (median 1, arbitrary scale) from the dense tracks ``tr`` of a video whose dynamic
    masks are ``masks [T,H,W]``; ``static [N]`` marks the tracks off the masks."""
    cfg = cfg or SfMConfig()
    if cfg.contact not in SFM_CONTACTS:
        raise ValueError(f"SfMConfig.contact {cfg.contact!r}: choose from {', '.join(SFM_CONTACTS)}")
    fill = CONTACT_RULES[cfg.contact]
    T, H, W = masks.shape
    rec, info = reconstruct(tr, static, K, cfg)
    if rec is None:
        a, b = info["pair"]
        if "failed" in info:
            why = f"structure from motion failed ({info['failed']})"
        elif info.get("fixed"):
            why = (f"the camera hardly moves (its static tracks move {info['motion_px']:.1f} px from frame {a} to "
                   f"frame {b}, no more than their {info['parallax_px']:.1f} px of parallax, which no second view "
                   "explains: a fixed camera's drift)")
        else:
            why = f"the camera hardly moves (parallax {info['parallax_px']:.1f} px between the best pair of frames)"
        msg = (f"{why}: depth cannot be recovered from the video, using a constant depth (scale arbitrary); give "
               "--depth FILE or a depth model for 3D structure")
        _log(cfg, msg)
        return SfMResult(np.ones((T, H, W), np.float32), np.tile(np.eye(4), (T, 1, 1)), False, msg, info)
    R, t, reg = rec
    _log(cfg, f"pair {info['pair']} (parallax {info['parallax_px']:.1f} px), {reg.sum()}/{T} frames registered, "
              f"BA loss {info['ba_loss'][0]:.3g} -> {info['ba_loss'][1]:.3g}")
    R, t = _fill_poses(R, t, reg)
    vis = tr.visible & reg[None]
    sel = np.flatnonzero(static & (vis.sum(1) >= 2))
    X, err, ang = triangulate(tr.tracks[sel], vis[sel], R, t, K)
    good = (err < cfg.reproj_px * 2) & (ang >= 0.25 * cfg.min_angle_deg)
    sel, X, ang = sel[good], X[good], ang[good]
    z_all = _camera_depths(R, t, X)
    scale = float(np.median(z_all[vis[sel] & (z_all > 0)]))
    weight = np.clip(ang / (4 * cfg.min_angle_deg), 0.05, 1.0)
    depth = np.ones((T, H, W), np.float32)
    for f in range(T):
        w = np.flatnonzero(vis[sel, f] & (z_all[:, f] > 0))
        if len(w) < 10:
            continue
        depth[f] = np.exp(fill(densify(tr.tracks[sel[w], f], np.log(z_all[w, f] / scale), H, W, weight[w]),
                               masks[f]))
    poses = invert_pose(pose_from_rt(R, t / scale))
    info.update(triangulated=int(len(sel)), scale=scale)
    msg = "depth from structure from motion: the scale is arbitrary (median depth 1)"
    _log(cfg, f"{msg}; {len(sel)} static tracks triangulated")
    return SfMResult(depth, poses, True, msg, info)
