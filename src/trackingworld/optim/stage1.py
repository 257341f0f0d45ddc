"""Stage 1: initial camera poses from static tracks, clip by clip (paper Sec. 3.3, "Initial camera pose
estimation").

The video is cut into clips of ``clip_len`` frames that share their end frames. In each clip every static
track visible in two frames a, b is unprojected at a with the depth prior and reprojected into b with the
clip's relative poses; the loss is the mean squared pixel error over all ordered pairs. All clips are solved
together as one batched problem; after a first convergence only inlier tracks (mean error under
``inlier_px``) are kept and the clips are solved again. Clips are then chained by SE(3) composition through
their shared frames (the authors add rotation vectors, exact only for small rotations).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from trackingworld.config import OptimConfig
from trackingworld.optim import lie


def clip_frames(T: int, clip_len: int) -> list[list[int]]:
    """Frame indices of each clip; consecutive clips share one frame."""
    step = max(1, clip_len - 1)
    return [list(range(s, min(s + clip_len, T))) for s in range(0, max(T - 1, 1), step)]


@dataclass
class ClipBatch:
    """Padded per-clip observations. uv [C,P,L,2] px, depth [C,P,L] m, vis [C,P,L] bool,
    weight [C,P] (1 for tracks in use), track [C,P] index into the input tracks (-1 for padding)."""

    frames: list[list[int]]
    uv: torch.Tensor
    depth: torch.Tensor
    vis: torch.Tensor
    weight: torch.Tensor
    track: np.ndarray


def build_clips(uv: np.ndarray, depth: np.ndarray, vis: np.ndarray, cfg: OptimConfig, rng: np.random.Generator,
                dtype, device) -> ClipBatch:
    """uv [N,T,2], depth [N,T], vis [N,T] of the static tracks -> a padded batch of clips."""
    T = vis.shape[1]
    frames = clip_frames(T, cfg.clip_len)
    L = cfg.clip_len
    picks = []
    for fr in frames:
        idx = np.flatnonzero(vis[:, fr].sum(1) >= 2)
        if len(idx) > cfg.max_clip_points:
            idx = np.sort(rng.choice(idx, cfg.max_clip_points, replace=False))
        picks.append(idx)
    C, P = len(frames), max(1, max(len(p) for p in picks))
    U = np.zeros((C, P, L, 2), np.float64)
    D = np.ones((C, P, L), np.float64)
    V = np.zeros((C, P, L), bool)
    track = np.full((C, P), -1, np.int64)
    for c, (fr, idx) in enumerate(zip(frames, picks, strict=True)):
        n, k = len(idx), len(fr)
        U[c, :n, :k] = uv[idx][:, fr]
        D[c, :n, :k] = depth[idx][:, fr]
        V[c, :n, :k] = vis[idx][:, fr]
        track[c, :n] = idx
    as_t = lambda a: torch.as_tensor(a, dtype=dtype, device=device)  # noqa: E731
    return ClipBatch(frames, as_t(U), as_t(D), torch.as_tensor(V, device=device), as_t(track >= 0), track)


def _pairs(L: int) -> list[tuple[int, int]]:
    return [(a, b) for a in range(L) for b in range(L) if a != b]


def pair_residuals(R: torch.Tensor, t: torch.Tensor, b: ClipBatch, K: torch.Tensor, a: int, c: int):
    """Residuals of pair (a -> c): pixels [C,P,2], mask [C,P], and the pieces the Jacobians need."""
    Ya = lie.unproject(b.uv[:, :, a], b.depth[:, :, a], K)
    Ra, Rc = R[:, a, None], R[:, c, None]
    X = (Ra.transpose(-1, -2) @ (Ya - t[:, a, None])[..., None])[..., 0]
    Yc = lie.transform(Rc, t[:, c, None], X)
    r = lie.project(Yc, K) - b.uv[:, :, c]
    m = b.weight * (b.vis[:, :, a] & b.vis[:, :, c] & (Yc[..., 2] > 1e-3))
    return r, m, Ya, Yc


def clip_loss(R, t, b: ClipBatch, K) -> torch.Tensor:
    """Mean squared reprojection error [C] of each clip over its ordered frame pairs."""
    L = b.uv.shape[2]
    num = torch.zeros(b.uv.shape[0], dtype=b.uv.dtype, device=b.uv.device)
    den = torch.zeros_like(num)
    for a, c in _pairs(L):
        r, m, _, _ = pair_residuals(R, t, b, K, a, c)
        num = num + (m * (r**2).sum(-1)).sum(1)
        den = den + m.sum(1)
    return num / den.clamp_min(1.0)


def track_errors(R, t, b: ClipBatch, K) -> torch.Tensor:
    """Mean reprojection error in px [C,P] of every track of every clip (inf when never observed)."""
    L = b.uv.shape[2]
    num = torch.zeros(b.uv.shape[:2], dtype=b.uv.dtype, device=b.uv.device)
    den = torch.zeros_like(num)
    for a, c in _pairs(L):
        r, m, _, _ = pair_residuals(R, t, b, K, a, c)
        m = (m > 0) | ((b.weight == 0) & b.vis[:, :, a] & b.vis[:, :, c])  # score dropped tracks too
        num = num + m * r.norm(dim=-1)
        den = den + m
    return torch.where(den > 0, num / den.clamp_min(1.0), torch.full_like(num, float("inf")))


def _normal_equations(R, t, b: ClipBatch, K):
    C, P, L = b.uv.shape[:3]
    H = torch.zeros(C, L, L, 6, 6, dtype=b.uv.dtype, device=b.uv.device)
    g = torch.zeros(C, L, 6, dtype=b.uv.dtype, device=b.uv.device)
    for a, c in _pairs(L):
        r, m, Ya, Yc = pair_residuals(R, t, b, K, a, c)
        Jp = lie.project_jacobian(Yc, K)  # [C,P,2,3]
        # rows written as cross products (j^T [Y]x = (j x Y)^T) instead of [C,P] batches of 3x3 products:
        # d r / d xi_c = Jp [-[Yc]x, I]; d r / d xi_a = M [[Ya]x, -I] with M = Jp Rc Ra^T (Ya = Ra X + ta)
        Jc = torch.cat([torch.linalg.cross(Yc[..., None, :].expand_as(Jp), Jp), Jp], -1)
        M = (Jp.reshape(C, 2 * P, 3) @ (R[:, c] @ R[:, a].transpose(-1, -2))).reshape(Jp.shape)
        Ja = torch.cat([torch.linalg.cross(M, Ya[..., None, :].expand_as(M)), -M], -1)
        # both frames' Jacobians side by side: one batched [12, 2P] x [2P, 12] product per clip gives the four
        # 6x6 blocks of the pair (instead of [C,P,6,6] products summed over P)
        J = torch.cat([Ja, Jc], -1).reshape(C, 2 * P, 12)
        JmT = (J * m.repeat_interleave(2, 1)[..., None]).transpose(1, 2)
        Hp = JmT @ J
        gp = (JmT @ r.reshape(C, 2 * P, 1))[..., 0]
        for i, si in ((a, slice(0, 6)), (c, slice(6, 12))):
            g[:, i] += gp[:, si]
            for j, sj in ((a, slice(0, 6)), (c, slice(6, 12))):
                H[:, i, j] += Hp[:, si, sj]
    H = H.permute(0, 1, 3, 2, 4).reshape(C, 6 * L, 6 * L)
    return H, g.reshape(C, 6 * L)


def solve_clips_lm(b: ClipBatch, K: torch.Tensor, iters: int, tol: float, R=None, t=None, log=None):
    """Levenberg-Marquardt on every clip at once (block-diagonal: one 6(L-1) system per clip); the first
    frame of each clip is the clip's reference. Returns w2c (R [C,L,3,3], t [C,L,3]) relative to it."""
    C, P, L = b.uv.shape[:3]
    dt, dev = b.uv.dtype, b.uv.device
    if R is None:
        R = torch.eye(3, dtype=dt, device=dev).repeat(C, L, 1, 1)
        t = torch.zeros(C, L, 3, dtype=dt, device=dev)
    mu = torch.full((C,), 1e-4, dtype=dt, device=dev)
    cost = clip_loss(R, t, b, K)
    eye = torch.eye(6 * (L - 1), dtype=dt, device=dev)
    done = torch.zeros(C, dtype=torch.bool, device=dev)
    for it in range(iters):
        H, g = _normal_equations(R, t, b, K)
        Hf, gf = H[:, 6:, 6:], g[:, 6:]
        diag = torch.diagonal(Hf, dim1=1, dim2=2)
        A = Hf + (mu[:, None, None] * torch.diag_embed(diag)) + 1e-9 * eye
        dx = torch.linalg.solve(A, -gf[..., None])[..., 0].reshape(C, L - 1, 6)
        R1, t1 = lie.update(R[:, 1:], t[:, 1:], dx)
        Rn, tn = torch.cat([R[:, :1], R1], 1), torch.cat([t[:, :1], t1], 1)
        new = clip_loss(Rn, tn, b, K)
        ok = new <= cost
        R = torch.where(ok[:, None, None, None], Rn, R)
        t = torch.where(ok[:, None, None], tn, t)
        # a clip has converged once a step changes its cost by less than tol (relative), taken or not: at its
        # minimum every step is rejected by rounding alone, and waiting for its damping to blow up cost 12
        # wasted iterations of the whole batch on a 30-frame scene
        done = done | ((cost - new).abs() < tol * cost + 1e-12) | (mu > 1e8)  # 1e-12 px^2: exact data
        cost = torch.where(ok, new, cost)
        mu = torch.where(ok, (mu / 3).clamp_min(1e-7), mu * 4)
        if log:
            log(it, float(cost.mean()))
        if bool(done.all()):
            break
    return R, t, cost


def solve_clips_adam(b: ClipBatch, K: torch.Tensor, iters: int, lr: float, R=None, t=None, log=None):
    """The paper's way: Adam on per-frame rotation vectors and translations of every clip."""
    C, P, L = b.uv.shape[:3]
    dt, dev = b.uv.dtype, b.uv.device
    if R is None:
        R = torch.eye(3, dtype=dt, device=dev).repeat(C, L, 1, 1)
        t = torch.zeros(C, L, 3, dtype=dt, device=dev)
    xi = torch.zeros(C, L - 1, 6, dtype=dt, device=dev, requires_grad=True)
    opt = torch.optim.Adam([xi], lr=lr, amsgrad=True)
    for it in range(iters):
        R1, t1 = lie.update(R[:, 1:], t[:, 1:], xi)
        loss = clip_loss(torch.cat([R[:, :1], R1], 1), torch.cat([t[:, :1], t1], 1), b, K)
        opt.zero_grad()
        loss.sum().backward()
        opt.step()
        if log and it % 100 == 0:
            log(it, float(loss.mean()))
    with torch.no_grad():
        R1, t1 = lie.update(R[:, 1:], t[:, 1:], xi)
        R, t = torch.cat([R[:, :1], R1], 1), torch.cat([t[:, :1], t1], 1)
        return R, t, clip_loss(R, t, b, K)


def chain_clips(frames: list[list[int]], R: torch.Tensor, t: torch.Tensor, T: int) -> np.ndarray:
    """Join clip-relative w2c poses into one camera-to-world trajectory ``[T,4,4]`` (frame 0 = identity)
    by SE(3) composition through each clip's first frame, which the previous clip already placed."""
    rel_c2w = lie.w2c_to_c2w(R, t)  # [C,L,4,4]: clip frame -> clip reference camera
    out = np.full((T, 4, 4), np.nan)
    out[0] = np.eye(4)
    for c, fr in enumerate(frames):
        anchor = out[fr[0]]
        for j, f in enumerate(fr[1:], start=1):
            out[f] = anchor @ rel_c2w[c, j]
    return out


MIN_POSE_TRACKS = 10  # static tracks a frame's pose is fitted to, below which the run says the pose is weak


def weak_frames(vis: np.ndarray, min_tracks: int = MIN_POSE_TRACKS) -> np.ndarray:
    """``[k]`` frame indices where fewer than ``min_tracks`` of the static tracks the poses are fitted to are
    visible (``vis [n,T]``): a pose there rests on too few points, and where none is seen the camera is held (its
    clip's relative motion stays the identity)."""
    return np.flatnonzero(vis.sum(0) < min_tracks)


def frame_ranges(frames: np.ndarray) -> str:
    """Sorted frame indices as runs: ``[0 1 2 5 7 8]`` -> ``"0-2, 5, 7-8"``."""
    frames = np.asarray(frames, np.int64)
    if not frames.size:
        return ""
    cut = np.flatnonzero(np.diff(frames) != 1) + 1
    runs = np.split(frames, cut)
    return ", ".join(f"{r[0]}" if len(r) == 1 else f"{r[0]}-{r[-1]}" for r in runs)


def pose_support_warning(weak: np.ndarray, T: int, static: int, tracks: int,
                         min_tracks: int = MIN_POSE_TRACKS) -> str | None:
    """One line for the user where the static tracks cannot place the cameras (None where they can): ``weak`` the
    frames of :func:`weak_frames` out of ``T``, ``static`` of ``tracks`` tracks outside the masks."""
    if not len(weak):
        return None
    masked = f" (the masks cover {100 * (1 - static / max(tracks, 1)):.0f}% of the {tracks:,} tracks)"
    if len(weak) == T and static == 0:
        return (f"no static track to place the cameras on{masked}: every frame keeps the first one's pose (a "
                f"fixed camera); if the camera moves, check the masks (non-zero = dynamic)")
    return (f"frame{'s' if len(weak) > 1 else ''} {frame_ranges(weak)} of {T}: fewer than {min_tracks} static tracks "
            f"seen to place the camera on{masked if static < tracks else ''}; those poses are weak, and held where "
            f"none is seen")


def initial_poses(uv: np.ndarray, depth: np.ndarray, vis: np.ndarray, K: np.ndarray, cfg: OptimConfig,
                  rng: np.random.Generator, device: str = "cpu", log=None):
    """Stage 1. uv [N,T,2] px, depth [N,T] prior metres, vis [N,T] of the static tracks, K [3,3].
    Returns camera-to-world poses ``[T,4,4]`` and a dict of diagnostics (losses, inlier fraction)."""
    T = vis.shape[1]
    dtype = getattr(torch, cfg.dtype)
    b = build_clips(uv, depth, vis, cfg, rng, dtype, device)
    Kt = torch.as_tensor(K, dtype=dtype, device=device)
    slog = (lambda it, loss: log("stage 1", it, loss)) if log else None
    rounds = 1 if cfg.no_inliers else 2
    R = t = None
    info: dict = {"clips": len(b.frames)}
    for rnd in range(rounds):
        if cfg.solver == "adam":
            R, t, cost = solve_clips_adam(b, Kt, cfg.adam_iters[0] // rounds, cfg.adam_lr, R, t, slog)
        else:
            R, t, cost = solve_clips_lm(b, Kt, cfg.lm_iters, cfg.lm_tol, R, t, slog)
        if rnd == 0 and rounds == 2:
            with torch.no_grad():
                err = track_errors(R, t, b, Kt)
                keep = (err < cfg.inlier_px) & (b.weight > 0)
                # a clip left with too few inliers keeps its best half instead of going blind
                for c in range(keep.shape[0]):
                    n_in, n_all = int(keep[c].sum()), int((b.weight[c] > 0).sum())
                    if n_in < max(8, n_all // 10) and n_all > 0:
                        thr = torch.quantile(err[c][b.weight[c] > 0], 0.5)
                        keep[c] = (err[c] <= thr) & (b.weight[c] > 0)
                info["inlier_fraction"] = float(keep.sum() / (b.weight > 0).sum().clamp_min(1))
                b.weight = keep.to(b.weight.dtype)
    info["loss"] = float(cost.mean())
    return chain_clips(b.frames, R.detach(), t.detach(), T), info
