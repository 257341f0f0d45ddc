"""Stage 2: dynamic background refinement (paper Sec. 3.3 and appendix).

Unknowns: world-to-camera poses (frame 0 fixed, it sets the gauge), static points ``X [N,3]`` and per-
observation offsets ``O(i,t)``; the camera sees ``R_t (X_i + O(i,t)) + t_t``. The objective, a mean over the
visible observations, is

    lambda_ba |pi(.) - uv|^2 [px^2]  +  lambda_dc (log z(.) - log D)^2  +  lambda_asap ||O||  [m].

The depth term is on log depth by default (``dc_space``): the prior's errors are multiplicative, and a
residual in metres lets far points dominate while (z - D) / D biases the scale low; ``metres`` is the paper
as written.

``||O||`` is taken as |tangential| + |radial| part in the camera (the paper's L1 depends on the world axes).

Structured solver (default). Each offset enters one observation only, so it can be minimised in closed
form: an offset of o metres across the ray moves the projection by o f / z pixels, and minimising
``lambda_ba (r - o f/z)^2 + lambda_asap o`` over o >= 0 gives the Huber cost of r with threshold
``c = lambda_asap z / (2 lambda_ba f)`` px (likewise ``lambda_asap z / (2 lambda_dc)`` for log depth). What remains
is bundle adjustment over poses and points with a Huber kernel, solved by Levenberg-Marquardt with iteratively
reweighted normal equations, the points eliminated by the Schur complement (3x3 blocks) and the reduced pose
system solved by conjugate gradients (memory and time linear in the number of observations), preconditioned
by block Jacobi plus an exact solve on a coarse space of smooth trajectory corrections (:func:`coarse_basis`).
The offsets are then read off the final residuals: ``|O| = (r - c) z / f``.

Focal length (optional, ``refine_focal``): one more unknown, ``phi = log(f / f0)`` scaling fx and fy together
(principal point fixed). The projection's derivative is ``d uv / d phi = uv - c``; in the structured solver the
unknown joins the reduced pose system as one extra row coupled to every pose and, through the Schur complement,
to every point.

Reference solver (``adam``, the paper's way): Adam on poses, points and explicit offsets (and phi).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np
import torch

from trackingworld.config import OptimConfig, offset_percentile
from trackingworld.geometry import transform, unproject
from trackingworld.optim import ba_blocks, lie, static_fit
from trackingworld.optim.linalg import pcg, sparse_csr


@dataclass
class BAProblem:
    """Observations of N points in T frames, flattened: pt, fr [M] long; uv [M,2] px; depth [M] prior metres.
    A point has at most one observation per frame (a track's position in a frame): the dense pose solve writes
    each (point, frame) block once."""

    pt: torch.Tensor
    fr: torch.Tensor
    uv: torch.Tensor
    depth: torch.Tensor
    n_points: int
    n_frames: int
    K: torch.Tensor
    lambda_ba: float = 1.0
    lambda_dc: float = 1.0
    lambda_asap: float = 5.0
    offsets: bool = True  # False: the "w/o O_static" ablation, plain least squares
    log_dc: bool = True  # depth residual log(z / D) instead of z - D metres (see OptimConfig.dc_space)
    # focal length (px) of the Huber thresholds; None: K's. A refined focal keeps the starting one here, so the
    # kernel stays the same in pixels: with the current focal, pixel errors would get cheaper as f grows.
    kernel_focal: float | None = None
    # per observation [M]: a factor on the depth term (its Huber threshold divided by it), None: 1 everywhere
    # (OptimConfig.ba_dc_parallax_rad, :func:`parallax_weights`)
    dc_weight: torch.Tensor | None = None

    @staticmethod
    def from_tracks(uv: np.ndarray, depth: np.ndarray, vis: np.ndarray, K: np.ndarray, cfg: OptimConfig,
                    dtype, device) -> BAProblem:
        """uv [N,T,2], depth [N,T], vis [N,T] -> flattened observations."""
        pt, fr = np.nonzero(vis)
        as_t = lambda a: torch.as_tensor(a, dtype=dtype, device=device)  # noqa: E731
        return BAProblem(
            torch.as_tensor(pt, device=device), torch.as_tensor(fr, device=device), as_t(uv[pt, fr]),
            as_t(depth[pt, fr]), vis.shape[0], vis.shape[1], as_t(K), cfg.lambda_ba,
            0.0 if cfg.no_depth_consistency else cfg.lambda_dc, cfg.lambda_asap, not cfg.no_offsets,
            cfg.dc_space == "log")

    def subset(self, keep: torch.Tensor) -> BAProblem:
        """The same problem with only the observations ``keep`` [M] bool (points and frames numbered as before)."""
        return replace(self, pt=self.pt[keep], fr=self.fr[keep], uv=self.uv[keep], depth=self.depth[keep],
                       dc_weight=None if self.dc_weight is None else self.dc_weight[keep])

    def with_focal_scale(self, phi) -> BAProblem:
        """The same problem with fx and fy multiplied by ``exp(phi)`` (phi a float or a 0-d tensor)."""
        s = torch.exp(torch.as_tensor(phi, dtype=self.K.dtype, device=self.K.device))
        diag = torch.stack([s, s, torch.ones_like(s)])
        scale = torch.diag_embed(diag - 1) + 1  # fx and fy scaled, principal point and skew kept
        return replace(self, K=self.K * scale, kernel_focal=float(self.kernel_f))

    @property
    def focal(self) -> torch.Tensor:
        return torch.sqrt(self.K[0, 0] * self.K[1, 1])

    @property
    def kernel_f(self):
        """Focal length (px) that turns the offsets' metres into the kernel's pixels (see ``kernel_focal``)."""
        return self.focal if self.kernel_focal is None else self.kernel_focal

    def thresholds(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Huber thresholds from the eliminated offsets: pixels [M] and depth-residual units [M]."""
        c_uv = self.lambda_asap * z.clamp_min(1e-3) / (2 * self.lambda_ba * self.kernel_f)
        c_d = self.lambda_asap * self.depth_scale(z) / (2 * max(self.lambda_dc, 1e-12))
        if self.dc_weight is not None:
            c_d = c_d / self.dc_weight.clamp_min(1e-12)
        return c_uv, c_d

    @property
    def dc_w(self):
        """The depth term's factor: 1, or per observation [M] (``dc_weight``)."""
        return 1.0 if self.dc_weight is None else self.dc_weight

    def depth_scale(self, z: torch.Tensor) -> torch.Tensor:
        """Metres of camera depth per unit of the depth residual at depth z [M]."""
        return z.clamp_min(1e-3) if self.log_dc else torch.ones_like(z)

    def depth_residual(self, z: torch.Tensor) -> torch.Tensor:
        if self.log_dc:
            return torch.log(z.clamp_min(1e-3)) - torch.log(self.depth.clamp_min(1e-3))
        return z - self.depth


def _huber(r: torch.Tensor, c) -> torch.Tensor:
    return torch.where(r <= c, r * r, 2 * c * r - c * c)


def residuals(R, t, X, p: BAProblem):
    """Camera points Y [M,3], pixel residuals [M,2], depth residuals [M]."""
    Y = lie.transform(R[p.fr], t[p.fr], X[p.pt])
    return Y, lie.project(Y, p.K) - p.uv, p.depth_residual(Y[:, 2])


def loss(R, t, X, p: BAProblem) -> torch.Tensor:
    """The stage-2 objective with every offset at its closed-form optimum (a mean over observations)."""
    Y, r_uv, r_d = residuals(R, t, X, p)
    e_uv, e_d = r_uv.norm(dim=-1), r_d.abs()
    if not p.offsets:
        return (p.lambda_ba * e_uv**2 + p.lambda_dc * p.dc_w * e_d**2).mean()
    c_uv, c_d = p.thresholds(Y[:, 2])
    cost = p.lambda_ba * _huber(e_uv, c_uv)
    if p.lambda_dc > 0:
        cost = cost + p.lambda_dc * p.dc_w * _huber(e_d, c_d)
    return cost.mean()


def offset_norms(R, t, X, p: BAProblem) -> torch.Tensor:
    """||O(i,t)|| [M] metres at the closed-form optimum (0 with offsets switched off)."""
    Y, r_uv, r_d = residuals(R, t, X, p)
    if not p.offsets:
        return torch.zeros_like(r_d)
    c_uv, c_d = p.thresholds(Y[:, 2])
    o_t = (r_uv.norm(dim=-1) - c_uv).clamp_min(0) * Y[:, 2].clamp_min(1e-3) / p.kernel_f
    o_r = (r_d.abs() - c_d).clamp_min(0) * p.depth_scale(Y[:, 2]) if p.lambda_dc > 0 else torch.zeros_like(o_t)
    return o_t + o_r


def explicit_objective(R, t, X, O, p: BAProblem) -> torch.Tensor:
    """The objective with explicit world offsets ``O [M,3]`` (what the Adam reference minimises)."""
    Y = lie.transform(R[p.fr], t[p.fr], X[p.pt] + O)
    r_uv = lie.project(Y, p.K) - p.uv
    r_d = p.depth_residual(Y[:, 2])
    dY = (R[p.fr] @ O[..., None])[..., 0]
    ray = Y / Y[:, 2:].clamp_min(1e-3)
    o_r = (dY * ray).sum(-1) / (ray * ray).sum(-1)
    o_t = (dY - o_r[:, None] * ray).norm(dim=-1)
    asap = (o_t + o_r.abs()) if p.offsets else torch.zeros_like(o_r)
    if p.kernel_focal is not None:  # a refined focal: the tangential offset priced at the starting focal
        asap = asap + o_t * (p.focal / p.kernel_f - 1)
    return (p.lambda_ba * (r_uv**2).sum(-1) + p.lambda_dc * p.dc_w * r_d**2 + p.lambda_asap * asap).mean()


def closed_form_offsets(R, t, X, p: BAProblem) -> torch.Tensor:
    """World offsets ``O [M,3]`` of the structured solver: the residual beyond the Huber threshold moved
    across the ray (pixels) and along it (depth)."""
    Y, r_uv, r_d = residuals(R, t, X, p)
    O = torch.zeros_like(Y)
    if not p.offsets:
        return O
    c_uv, c_d = p.thresholds(Y[:, 2])
    e = r_uv.norm(dim=-1).clamp_min(1e-12)
    s = -(1 - (c_uv / e).clamp(max=1))[:, None] * r_uv  # pixel shift that leaves a residual of c
    J = lie.project_jacobian(Y, p.K)
    dY = (J.transpose(-1, -2) @ torch.linalg.solve(J @ J.transpose(-1, -2), s[..., None]))[..., 0]
    if p.lambda_dc > 0:
        o_r = -torch.sign(r_d) * (r_d.abs() - c_d).clamp_min(0) * p.depth_scale(Y[:, 2])
        dY = dY + o_r[:, None] * Y / Y[:, 2:].clamp_min(1e-3)
    return (R[p.fr].transpose(-1, -2) @ dY[..., None])[..., 0]


@dataclass
class _FocalBlocks:
    """Gauss-Newton blocks of the focal unknown phi: Hff, gf scalars, Hcf [T,6], Hxf [N,3]."""

    Hff: torch.Tensor
    gf: torch.Tensor
    Hcf: torch.Tensor
    Hxf: torch.Tensor


# the compiled CPU kernels (optim.ba_blocks: the Gauss-Newton blocks and the dense Schur step; optim.point_fit: the
# rigid step's membership test) on CPU float64 tensors, and optim.static_fit (the static tests' point fits) on CPU
# float32 ones (False: torch's code everywhere, the reference; for measuring the two against each other)
COMPILED = True


def compiled(x: torch.Tensor) -> bool:
    """Whether work on tensors like ``x`` runs the compiled CPU kernels (:data:`COMPILED`, a CPU float64 tensor)."""
    return COMPILED and x.device.type == "cpu" and x.dtype == torch.float64


def _np(x: torch.Tensor) -> np.ndarray:
    """The array behind a CPU tensor (no copy)."""
    return x.detach().numpy()


def _linearize(R, t, X, p: BAProblem, points_only: bool = False, focal: bool = False):
    """Gauss-Newton blocks (Hcc, Hxx, Hcx, gc, gx) of the IRLS-weighted problem; with ``points_only`` the pose
    blocks are skipped (returned as None): what a fit of the points with the poses held fixed needs. With
    ``focal`` a sixth item holds the blocks of phi (:class:`_FocalBlocks`)."""
    if not focal and compiled(R):  # optim.ba_blocks
        return _linearize_compiled(R, t, X, p, points_only)
    Y, r_uv, r_d = residuals(R, t, X, p)
    M = Y.shape[0]
    w_uv = torch.ones_like(r_d)
    w_d = torch.ones_like(r_d)
    if p.offsets:  # IRLS weights of the Huber kernels
        c_uv, c_d = p.thresholds(Y[:, 2])
        w_uv = (c_uv / r_uv.norm(dim=-1).clamp_min(1e-12)).clamp(max=1)
        w_d = (c_d / r_d.abs().clamp_min(1e-12)).clamp(max=1)
    W = torch.stack([p.lambda_ba * w_uv, p.lambda_ba * w_uv, p.lambda_dc * p.dc_w * w_d], -1) / M
    ez = torch.zeros_like(Y[:, None])
    ez[..., 2] = 1.0 / p.depth_scale(Y[:, 2])[:, None]
    JY = torch.cat([lie.project_jacobian(Y, p.K), ez], 1)  # [M,3,3]
    r = torch.cat([r_uv, r_d[:, None]], 1)
    Jx = JY @ R[p.fr]  # [M,3,3]
    WJx = W[..., None] * Jx
    T, N = p.n_frames, p.n_points
    if points_only:
        Hxx = torch.zeros(N, 3, 3, dtype=Y.dtype, device=Y.device).index_add_(0, p.pt, Jx.transpose(1, 2) @ WJx)
        gx = torch.zeros(N, 3, dtype=Y.dtype, device=Y.device).index_add_(0, p.pt, _mv(WJx, r))
        return None, Hxx, None, None, gx
    Jc = JY @ lie.pose_jacobian(Y)  # [M,3,6]
    WJc = W[..., None] * Jc
    Hcc = torch.zeros(T, 6, 6, dtype=Y.dtype, device=Y.device).index_add_(0, p.fr, Jc.transpose(1, 2) @ WJc)
    Hxx = torch.zeros(N, 3, 3, dtype=Y.dtype, device=Y.device).index_add_(0, p.pt, Jx.transpose(1, 2) @ WJx)
    Hcx = Jc.transpose(1, 2) @ WJx  # [M,6,3]
    gc = torch.zeros(T, 6, dtype=Y.dtype, device=Y.device).index_add_(0, p.fr, _mv(WJc, r))
    gx = torch.zeros(N, 3, dtype=Y.dtype, device=Y.device).index_add_(0, p.pt, _mv(WJx, r))
    if not focal:
        return Hcc, Hxx, Hcx, gc, gx
    Jf = torch.cat([r_uv + p.uv - p.K[:2, 2], torch.zeros_like(r_d)[:, None]], 1)  # d residual / d phi [M,3]
    WJf = W * Jf
    fb = _FocalBlocks(
        (WJf * Jf).sum(), (WJf * r).sum(),
        torch.zeros(T, 6, dtype=Y.dtype, device=Y.device).index_add_(0, p.fr, _mv(Jc, WJf)),
        torch.zeros(N, 3, dtype=Y.dtype, device=Y.device).index_add_(0, p.pt, _mv(Jx, WJf)))
    return Hcc, Hxx, Hcx, gc, gx, fb


def _problem_args(p: BAProblem) -> tuple:
    """The problem ``p`` as the compiled kernels take it: observations ``pt, fr``, ``uv``, ``depth``, ``K``, the
    weights, ``offsets``, ``log_dc``, the kernel's focal length and the depth weights (arrays behind the tensors)."""
    return (_np(p.pt), _np(p.fr), _np(p.uv), _np(p.depth), _np(p.K), (p.lambda_ba, p.lambda_dc, p.lambda_asap),
            p.offsets, p.log_dc, None if p.kernel_focal is None else float(p.kernel_focal),
            None if p.dc_weight is None else _np(p.dc_weight))


def _kernel_args(R, t, X, p: BAProblem) -> tuple:
    """The arguments of :func:`trackingworld.optim.ba_blocks.linearize` and ``cost`` for the problem ``p``."""
    return (_np(R), _np(t), _np(X)) + _problem_args(p)


def _linearize_compiled(R, t, X, p: BAProblem, points_only: bool):
    """:func:`_linearize` (no focal unknown) by :func:`trackingworld.optim.ba_blocks.linearize`, on CPU float64
    tensors."""
    Hcc, Hxx, Hcx, gc, gx = (torch.from_numpy(b) for b in ba_blocks.linearize(*_kernel_args(R, t, X, p), points_only))
    return (None, Hxx, None, None, gx) if points_only else (Hcc, Hxx, Hcx, gc, gx)


def loss_value(R, t, X, p: BAProblem) -> float:
    """:func:`loss` as a float, by the compiled kernel (:func:`trackingworld.optim.ba_blocks.cost`) where
    :func:`compiled` says so."""
    if compiled(R):
        return ba_blocks.cost(*_kernel_args(R, t, X, p))
    return float(loss(R, t, X, p))


def _mv(J: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """J^T r for stacks J [M,k,n], r [M,k] -> [M,n]."""
    return (J.transpose(1, 2) @ r[..., None])[..., 0]


def _damp(H: torch.Tensor, mu: float) -> torch.Tensor:
    d = torch.diagonal(H, dim1=-2, dim2=-1)
    return H + torch.diag_embed(mu * d + 1e-12 * (1 + d.abs().amax(-1, keepdim=True)))


def _point_pose_operator(G: torch.Tensor, pt: torch.Tensor, fr: torch.Tensor, N: int, T: int):
    """The point-pose coupling ``B [3N, 6T]`` with block (pt_m, fr_m) = ``G[m]^T`` (G [M,6,3]), and its
    transpose, as sparse CSR matrices: the reduced pose system's product ``B^T B v`` then costs two sparse
    matrix-vector products (about 3x faster on a CPU than gathering and scattering the 6x3 blocks, and linear
    in the observations, unlike forming the reduced matrix, whose pairs of observations grow with their
    square). The layout is written directly (one sort of the observations, none of the 18 M entries): rows of
    B are (point, axis j) with the point's observations in frame order, 6 entries (pose coordinate i) each;
    rows of B^T are (frame, i) with the frame's observations in point order, 3 entries (j) each."""
    M, dev = len(pt), pt.device
    ar = torch.arange(M, device=dev)
    i6 = torch.arange(6, device=dev)[None, :, None]
    j3 = torch.arange(3, device=dev)[None, None, :]

    def layout(major, minor, n_major):
        o = torch.argsort(major * max(N, T) + minor)  # observations by (major, minor)
        cnt = torch.bincount(major, minlength=n_major)
        start = torch.cumsum(cnt, 0) - cnt
        rank = torch.empty_like(ar)
        rank[o] = ar - start[major[o]]
        return cnt, start, rank

    def csr(pos, col, cnt, start, width, shape):
        vals = torch.empty(M * 18, dtype=G.dtype, device=dev)
        vals[pos.reshape(-1)] = G.reshape(-1)
        cols = torch.empty(M * 18, dtype=torch.long, device=dev)
        cols[pos.reshape(-1)] = col.reshape(-1)
        sub = torch.arange(18 // width, device=dev)  # rows per point (3) or per frame (6)
        crow = (18 * start[:, None] + width * sub[None] * cnt[:, None]).reshape(-1)
        crow = torch.cat([crow, torch.full((1,), M * 18, dtype=torch.long, device=dev)])
        return sparse_csr(crow, cols, vals, shape)

    cnt, start, rank = layout(pt, fr, N)  # B: row 3 pt + j, entry 6 rank + i
    pos = 18 * start[pt][:, None, None] + 6 * cnt[pt][:, None, None] * j3 + 6 * rank[:, None, None] + i6
    B = csr(pos, (6 * fr[:, None, None] + i6).expand(M, 6, 3), cnt, start, 6, (3 * N, 6 * T))
    cnt, start, rank = layout(fr, pt, T)  # B^T: row 6 fr + i, entry 3 rank + j
    pos = 18 * start[fr][:, None, None] + 3 * cnt[fr][:, None, None] * i6 + 3 * rank[:, None, None] + j3
    BT = csr(pos, (3 * pt[:, None, None] + j3).expand(M, 6, 3), cnt, start, 3, (6 * T, 3 * N))
    return B, BT


COARSE_SPACING = 8  # frames between the nodes of the pose PCG's coarse space; 0: block Jacobi only


def coarse_basis(free: torch.Tensor, spacing: int, dtype, device) -> torch.Tensor | None:
    """Coarse space of the reduced pose system, ``[6T, 6S]``: piecewise-linear hat functions of the frame index
    with nodes every ``spacing`` frames and at the last frame, one column per node and pose coordinate, zero on
    the fixed frames (``free [T]`` bool). None when the video is not longer than ``spacing`` frames."""
    T = len(free)
    if spacing <= 0 or T <= spacing:
        return None
    nodes = np.unique(np.r_[np.arange(0, T, spacing), T - 1])
    hats = np.stack([np.interp(np.arange(T), nodes, e) for e in np.eye(len(nodes))], 1)  # [T,S]
    hats *= free.cpu().numpy()[:, None]
    hats = hats[:, hats.any(0)]
    return torch.as_tensor(np.kron(hats, np.eye(6)), dtype=dtype, device=device)


# a reduced pose system formed densely (3N (6T)^2 multiply-adds) up to this size, else PCG. Stop 59, 2-core CPU, one
# reduced solve on random problems: 800 points x 96 / 120 frames (8e8 / 1.2e9) 27 / 37 ms dense against 50 / 61 ms
# PCG, 800 x 200 (3.5e9) 102 against 79 ms. With 2e9 instead of 5e8 the 120-frame video's rigid step (group fits
# over 75-150 frames) took 29.5 -> 24.2 s and 854x480's stage 2 3.6 -> 2.2-2.7 s, the same labels, positions within 2 um
DENSE_POSE_FLOPS = 2e9
DENSE_POSE_ENTRIES = 1e7  # ... and its point-pose coupling (3N x 6T numbers) up to this many (80 MB in float64)
# the compiled step (optim.ba_blocks.schur_step, float64 on a CPU) forms the reduced system densely up to this cost
# (optim.ba_blocks.reduced_cost, multiply-adds of BLAS) and this many frames (a 2400 x 2400 system, 46 MB), else
# PCG. Stop 70, 2-core CPU, one step on random problems, dense against PCG: 800 points seen in half to all of 120 /
# 200 / 300 / 400 frames (cost 6.2e8 / 1.7e9 / 3.9e9 / 6.9e9) 83 / 144 / 430 / 737 ms against 401 / 550 / 941 /
# 1,470 ms; 8,000 / 20,000 / 30,000 points seen in 5-30 frames of 120 / 120 / 30 (the pairs, 9.4e8 / 2.3e9 /
# 3.5e9) 76 / 213 / 232 ms against 775 / 2,219 / 2,984 ms. Stage 2 of the 120-frame video of bench_scaling.py
# (8,161 points): 0.12 s a step against 0.38 s
COMPILED_DENSE_COST = 1e10
COMPILED_DENSE_FRAMES = 400


def _dense_pose_solve(G, Hcc_d, Hcf, Hff_d, w, rhs, p: BAProblem, free: torch.Tensor, use_f: bool):
    """The reduced pose system of :func:`_schur_step` formed as a dense matrix and solved by Cholesky: for
    small problems (a rigid group's few hundred points, a short clip), where one factorisation costs less than
    PCG's iterations over the sparse operators. Same packing as the PCG (``rhs [T+1,6]``); None when the
    matrix is not positive definite (the caller falls back to PCG)."""
    T, N = p.n_frames, p.n_points
    n = 6 * T + int(use_f)
    dev, dt = G.device, G.dtype
    # B [3N, n]: each observation's block G^T at (its point, its frame), written once per (point, frame) pair
    # (BAProblem); assigning through a [N,3,T,6] view of the pose columns is 3-8x faster than accumulating
    # scattered entries
    Bd = torch.zeros(3 * N, n, dtype=dt, device=dev)
    Bd[:, : 6 * T].view(N, 3, T, 6)[p.pt, :, p.fr, :] = G.transpose(1, 2)
    if use_f:
        Bd[:, 6 * T] = w
    A = -(Bd.T @ Bd)
    r6 = 6 * torch.arange(T, device=dev)[:, None] + torch.arange(6, device=dev)  # [T,6] each frame's rows
    A[r6[:, :, None], r6[:, None, :]] += Hcc_d
    if use_f:
        A[: 6 * T, 6 * T] += Hcf.reshape(-1)
        A[6 * T, : 6 * T] += Hcf.reshape(-1)
        A[6 * T, 6 * T] += Hff_d
    fixed = torch.cat([(~free).repeat_interleave(6), torch.zeros(n - 6 * T, dtype=torch.bool, device=dev)])
    A[fixed] = 0
    A[:, fixed] = 0
    A[fixed, fixed] = 1
    b = rhs.reshape(-1)[:n] if use_f else rhs[:T].reshape(-1)
    Lc, bad = torch.linalg.cholesky_ex(0.5 * (A + A.T))
    if int(bad):
        return None
    x = torch.cholesky_solve(b[:, None], Lc)[:, 0]
    out = torch.zeros_like(rhs)
    out.view(-1)[:n] = x
    return out


def _pcg_pose_solve(G, Hcc, Hcc_d, Hxx_inv, fb: _FocalBlocks, Hff_d, w, rhs, p: BAProblem, free: torch.Tensor,
                    use_f: bool) -> torch.Tensor:
    """The reduced pose system of :func:`_schur_step` solved by PCG over sparse operators (linear in the
    observations): with G = Hcx L per observation the system is Hcc - B^T B (B from G). Same packing as
    :func:`_dense_pose_solve`."""
    T, N = p.n_frames, p.n_points
    fmask = free[:, None].to(Hcc.dtype)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")
        B, BT = _point_pose_operator(G, p.pt, p.fr, N, T)

    def unpack(v):
        return v[:T] * fmask, v[T, 0] if use_f else torch.zeros_like(v[T, 0])

    def matvec(v):
        vc, vf = unpack(v)
        u = B @ vc.reshape(-1) + w * vf
        out = torch.zeros_like(v)
        out[:T] = ((Hcc_d @ vc[..., None])[..., 0] + fb.Hcf * vf - (BT @ u).view(T, 6)) * fmask
        if use_f:
            out[T, 0] = (fb.Hcf * vc).sum() + Hff_d * vf - (w * u).sum()
        return out

    blocks = Hcc_d - torch.zeros_like(Hcc).index_add_(0, p.fr, G @ G.transpose(1, 2))
    eye = torch.eye(6, dtype=Hcc.dtype, device=Hcc.device)
    blocks = torch.where(free[:, None, None], blocks, eye)
    B_inv = torch.linalg.inv(blocks)
    s_ff = (Hff_d - (fb.Hxf * (Hxx_inv @ fb.Hxf[..., None])[..., 0]).sum()).clamp_min(1e-30)

    # two-level preconditioner: block Jacobi plus an exact solve on a coarse space of smooth trajectory
    # corrections. Block Jacobi alone leaves the slow, global modes (the whole trajectory bending), and its
    # iterations grew with the length (38 at 30 frames, 101 at 120); with the coarse space 17 and 19
    Z = coarse_basis(free, COARSE_SPACING, Hcc.dtype, Hcc.device)
    if Z is not None:
        fmask6 = fmask.repeat_interleave(6, 0)

        def poses_times(V):  # the reduced system's pose block times V [6T,k]
            k = V.shape[1]
            HV = (Hcc_d @ V.reshape(T, 6, k)).reshape(6 * T, k)
            return (HV - BT @ (B @ V)) * fmask6

        # in column chunks: B @ V is [3N, k], kept to about 8M numbers
        k = max(1, min(48, 2**23 // max(3 * N, 1)))
        Ac = Z.T @ torch.cat([poses_times(Z[:, i:i + k]) for i in range(0, Z.shape[1], k)], 1)
        Lc, bad = torch.linalg.cholesky_ex(0.5 * (Ac + Ac.T))
        if int(bad):
            Z = None

    def precond(r):
        out = torch.zeros_like(r)
        out[:T] = (B_inv @ r[:T, ..., None])[..., 0]
        if Z is not None:
            out[:T] += (Z @ torch.cholesky_solve(Z.T @ r[:T].reshape(-1, 1), Lc)).view(T, 6)
        out[T, 0] = r[T, 0] / s_ff
        return out

    return pcg(matvec, rhs, precond, iters=max(60, 6 * T))


def _schur_step(Hcc, Hxx, Hcx, gc, gx, p: BAProblem, mu: float, free: torch.Tensor,
                fb: _FocalBlocks | None = None):
    """One damped Gauss-Newton step: the points eliminated (Schur complement), poses (and phi) by a dense Cholesky
    solve where the reduced system is small (:data:`COMPILED_DENSE_COST` for the compiled step, else
    :data:`DENSE_POSE_FLOPS`), else by PCG.
    Returns (dc [T,6], dx [N,3], dphi float)."""
    if fb is None and compiled(Hcc) and p.n_frames <= COMPILED_DENSE_FRAMES:
        # the same step compiled (optim.ba_blocks), with the reduced system formed the cheaper of two ways; None
        # where that system is not positive definite, which the code below hands to PCG
        pt = _np(p.pt)
        how, cost = ba_blocks.reduced_cost(pt, p.n_points, p.n_frames)
        if cost <= COMPILED_DENSE_COST:
            out = ba_blocks.schur_step(_np(Hcc), _np(Hxx), _np(Hcx), _np(gc), _np(gx), pt, _np(p.fr), mu, _np(free),
                                       how)
            if out is not None:
                return torch.from_numpy(out[0]), torch.from_numpy(out[1]), 0.0
    dense = 3 * p.n_points * (6 * p.n_frames) ** 2 <= DENSE_POSE_FLOPS and 3 * p.n_points * 6 * p.n_frames <= \
        DENSE_POSE_ENTRIES
    # Hxx^-1 = L L^T from the eigen-decomposition of the damped 3x3 blocks (robust where a block is near
    # singular, e.g. a point seen along one ray without depth consistency)
    lam, V = torch.linalg.eigh(_damp(Hxx, mu))
    L = V * lam.clamp_min(1e-300).rsqrt()[:, None, :]
    Hxx_inv = L @ L.transpose(1, 2)
    Hcc_d = _damp(Hcc, mu)
    T = p.n_frames
    fmask = free[:, None].to(Hcc.dtype)
    if fb is None:  # no focal unknown: zero couplings keep one code path
        fb = _FocalBlocks(torch.zeros((), dtype=Hcc.dtype, device=Hcc.device), torch.zeros_like(Hcc[0, 0, 0]),
                          torch.zeros_like(gc), torch.zeros_like(gx))
        use_f = False
    else:
        use_f = True
    Hff_d = fb.Hff * (1 + mu) + 1e-12
    # with G = Hcx L per observation the reduced pose system is Hcc - B^T B (B from G)
    G = Hcx @ L[p.pt]  # [M,6,3]
    w = (L.transpose(1, 2) @ fb.Hxf[..., None])[..., 0].reshape(-1)  # L^T Hxf, the focal column of B
    y = (Hxx_inv @ gx[..., None])[..., 0]
    # the unknown is packed as [T+1, 6]: rows 0..T-1 the poses, row T column 0 phi (the rest unused)
    rhs = torch.zeros(T + 1, 6, dtype=gc.dtype, device=gc.device)
    rhs[:T] = -(gc - torch.zeros_like(gc).index_add_(0, p.fr, (Hcx @ y[p.pt][..., None])[..., 0])) * fmask
    if use_f:
        rhs[T, 0] = -(fb.gf - (fb.Hxf * y).sum())
    sol = None
    if dense:
        sol = _dense_pose_solve(G, Hcc_d, fb.Hcf, Hff_d, w, rhs, p, free, use_f)
    if sol is None:
        sol = _pcg_pose_solve(G, Hcc, Hcc_d, Hxx_inv, fb, Hff_d, w, rhs, p, free, use_f)
    dc = sol[:T] * fmask
    df = sol[T, 0] if use_f else torch.zeros_like(sol[T, 0])
    back = torch.zeros_like(gx).index_add_(0, p.pt, (Hcx.transpose(1, 2) @ dc[p.fr][..., None])[..., 0])
    dx = -(Hxx_inv @ (gx + back + fb.Hxf * df)[..., None])[..., 0]
    return dc, dx, float(df)


@dataclass
class BASolution:
    """World-to-camera R [T,3,3], t [T,3], points X [N,3], the final objective, K [3,3] (refined when asked),
    and the explicit offsets O [M,3] of the Adam reference (None for the structured solver)."""

    R: torch.Tensor
    t: torch.Tensor
    X: torch.Tensor
    cost: float
    K: torch.Tensor
    O: torch.Tensor | None = None


MAX_FOCAL_STEP = 0.2  # largest change of log focal length per LM step (a guard on weakly determined focal)


def levenberg_marquardt(state, cost: float, linearize, trial, iters: int, tol: float, log=None, label: str = ""):
    """Marquardt's damping schedule, shared by :func:`solve_lm` and :func:`fit_poses`: ``linearize(state)`` gives the
    blocks of a step, ``trial(state, blocks, mu)`` a candidate state and its cost under damping ``mu``. A candidate
    is taken when it does not raise ``cost`` (``mu`` x8 until one does not, or ``mu`` passes 1e6; /4 after a taken
    one); the loop ends after ``iters`` steps, at a step it could not take, or when the cost falls by less than
    ``tol`` of itself. Returns (the state, its cost)."""
    mu = 1e-4
    for it in range(iters):
        blocks = linearize(state)
        while True:
            cand, new = trial(state, blocks, mu)
            if new <= cost or mu > 1e6:
                break
            mu *= 8
        if new > cost:
            break
        rel = (cost - new) / max(cost, 1e-300)
        state, cost = cand, new
        mu = max(mu / 4, 1e-8)
        if log:
            log(label, it, cost)
        if rel < tol:
            break
    return state, cost


def solve_lm(R, t, X, p: BAProblem, iters: int = 30, tol: float = 1e-6, log=None,
             refine_focal: bool = False) -> BASolution:
    """Levenberg-Marquardt on poses and points, and the focal length with ``refine_focal`` (see the module
    docstring). Frame 0 stays fixed."""
    free = torch.ones(p.n_frames, dtype=torch.bool, device=R.device)
    free[0] = False

    def linearize(state):
        R, t, X, phi = state
        pk = p.with_focal_scale(phi) if refine_focal else p
        return pk, _linearize(R, t, X, pk, focal=refine_focal)

    def trial(state, blocks, mu):
        R, t, X, phi = state
        pk, (Hcc, Hxx, Hcx, gc, gx, *fb) = blocks
        dc, dx, df = _schur_step(Hcc, Hxx, Hcx, gc, gx, pk, mu, free, fb[0] if fb else None)
        df = float(np.clip(df, -MAX_FOCAL_STEP, MAX_FOCAL_STEP))
        Rn, tn = lie.update(R, t, dc)
        Xn = X + dx
        new = loss_value(Rn, tn, Xn, p.with_focal_scale(phi + df) if refine_focal else p)
        return (Rn, tn, Xn, phi + df), new

    (R, t, X, phi), cost = levenberg_marquardt((R, t, X, 0.0), loss_value(R, t, X, p), linearize, trial, iters, tol,
                                               log, "stage 2")
    return BASolution(R, t, X, cost, p.with_focal_scale(phi).K if refine_focal else p.K)


def fit_poses(R, t, X, p: BAProblem, iters: int = 30, tol: float = 1e-6) -> tuple[torch.Tensor, torch.Tensor]:
    """World-to-camera poses ``R [T,3,3]``, ``t [T,3]`` fitted with the points ``X [N,3]`` held fixed:
    Levenberg-Marquardt on the same objective, every frame's 6 unknowns solved alone (with the points fixed the
    frames do not couple), so a step costs the observations', not the frames' square. Every frame moves."""

    def trial(state, blocks, mu):
        Hcc, _, _, gc, _ = blocks
        Rn, tn = lie.update(*state, -torch.linalg.solve(_damp(Hcc, mu), gc[..., None])[..., 0])
        return (Rn, tn), loss_value(Rn, tn, X, p)

    (R, t), _ = levenberg_marquardt((R, t), loss_value(R, t, X, p), lambda s: _linearize(*s, X, p), trial, iters, tol)
    return R, t


def refine_focal(sol: BASolution, p: BAProblem, moving: np.ndarray, inlier_px: float = 3.0, iters: int = 30,
                 tol: float = 1e-9, log=None) -> BASolution:
    """The focal length from a stage-2 solution: bundle adjustment with the focal length free (least squares,
    no offsets) over the observations of the tracks not flagged ``moving [N]`` whose reprojection error is below
    ``inlier_px``. The full objective is not used for this: its offsets price every mover's pixel error, which
    shrinks with the focal length, so it prefers too short a focal length whenever something moves.
    Returns poses, the points it saw, the cost of that fit and the refined K."""
    with torch.no_grad():
        _, r_uv, _ = residuals(sol.R, sol.t, sol.X, p)
    keep = ~torch.as_tensor(moving, device=p.pt.device)[p.pt] & (r_uv.norm(dim=-1) < inlier_px)
    q = replace(p, pt=p.pt[keep], fr=p.fr[keep], uv=p.uv[keep], depth=p.depth[keep], offsets=False)
    return solve_lm(sol.R, sol.t, sol.X, q, iters, tol, log, refine_focal=True)


def solve_adam(R, t, X, p: BAProblem, iters: int = 2000, lr: float = 1e-3, log=None,
               refine_focal: bool = False) -> BASolution:
    """The paper's way: Adam (amsgrad) on pose updates, points and explicit offsets ``O [M,3]`` (and phi with
    ``refine_focal``)."""
    xi = torch.zeros(p.n_frames, 6, dtype=R.dtype, device=R.device, requires_grad=True)
    Xp = X.clone().requires_grad_(True)
    O = torch.zeros(p.pt.shape[0], 3, dtype=R.dtype, device=R.device, requires_grad=p.offsets)
    phi = torch.zeros((), dtype=R.dtype, device=R.device, requires_grad=refine_focal)
    params = [xi, Xp] + ([O] if p.offsets else []) + ([phi] if refine_focal else [])
    opt = torch.optim.Adam(params, lr=lr, amsgrad=True)
    gauge = torch.ones(p.n_frames, 1, dtype=R.dtype, device=R.device)
    gauge[0] = 0
    for it in range(iters):
        Rn, tn = lie.update(R, t, xi * gauge)
        obj = explicit_objective(Rn, tn, Xp, O, p.with_focal_scale(phi))
        opt.zero_grad()
        obj.backward()
        opt.step()
        if log and it % 100 == 0:
            log("stage 2 adam", it, float(obj))
    with torch.no_grad():
        Rn, tn = lie.update(R, t, xi * gauge)
        pk = p.with_focal_scale(phi)
        return BASolution(Rn, tn, Xp.detach(), float(explicit_objective(Rn, tn, Xp, O, pk)), pk.K.detach(),
                          O.detach())


def parallax_weights(uv: np.ndarray, depth: np.ndarray, obs: np.ndarray, query_frame: np.ndarray,
                     poses_c2w: np.ndarray, K: np.ndarray, p0: float) -> np.ndarray:
    """Each point's factor on stage 2's depth term, ``p0^2 / (p0^2 + a^2)`` ``[n]``: ``a`` (radians) the angle
    between the rays from the camera centres of its first and last observations (``obs [n,T]``) to the point its
    query pixel (``uv [n,T,2]`` px, ``query_frame [n]``) unprojects to at the prior depth (``depth [n,T]``
    metres), under the starting poses (camera-to-world ``[T,4,4]``). A point seen from far apart (a >> p0) is
    placed by its parallax, one seen from nearby (a << p0) by the prior, as with every point alike."""
    q = query_frame.astype(np.int64)
    rows = np.arange(len(obs))
    X = transform(poses_c2w[q], unproject(uv[rows, q].astype(np.float64), depth[rows, q].astype(np.float64), K))
    first = obs.argmax(1)
    last = obs.shape[1] - 1 - obs[:, ::-1].argmax(1)
    a, b = X - poses_c2w[first, :3, 3], X - poses_c2w[last, :3, 3]
    cos = (a * b).sum(1) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-12)
    angle = np.arccos(np.clip(cos, -1.0, 1.0))
    return p0**2 / (p0**2 + angle**2)


def init_points(R, t, p: BAProblem) -> torch.Tensor:
    """Mean of each point's back-projections with the prior depth over its visible frames [N,3]."""
    Yc = lie.unproject(p.uv, p.depth, p.K)
    Xw = (R[p.fr].transpose(1, 2) @ (Yc - t[p.fr])[..., None])[..., 0]
    s = torch.zeros(p.n_points, 3, dtype=Xw.dtype, device=Xw.device).index_add_(0, p.pt, Xw)
    n = torch.zeros(p.n_points, dtype=Xw.dtype, device=Xw.device).index_add_(0, p.pt, torch.ones_like(p.depth))
    return s / n.clamp_min(1)[:, None]


def track_offset_stat(norms: torch.Tensor, p: BAProblem, stat: str = "max") -> np.ndarray:
    """Per-point statistic [N] of ||O(i,t)|| over the visible frames: max (paper) or a percentile pNN."""
    norms = norms.detach()
    pct = offset_percentile(stat)
    if pct is None:
        out = torch.zeros(p.n_points, dtype=norms.dtype, device=norms.device)
        out.scatter_reduce_(0, p.pt, norms, reduce="amax", include_self=True)
        return out.cpu().numpy()
    q, counts = point_quantiles(norms.cpu().numpy(), p.pt.cpu().numpy(), p.n_points, (pct / 100,))
    return np.where(counts > 0, q[:, 0], 0.0)


def point_quantiles(v: np.ndarray, pt: np.ndarray, n: int, fracs) -> tuple[np.ndarray, np.ndarray]:
    """Per point, quantiles of the observations' values ``v [M]`` (``pt [M]`` the point of each): ``[n, len(fracs)]``,
    for each fraction the value at rank ``floor(frac * (count - 1))`` of the point's sorted values (NaN for a point
    without observations), and each point's observation count ``[n]``."""
    v, counts, starts = _sorted_by_point(v, pt, n)
    has = counts > 0
    out = np.full((n, len(fracs)), np.nan)
    for j, frac in enumerate(fracs):
        out[has, j] = v[starts[has] + np.floor(frac * (counts[has] - 1)).astype(np.int64)]
    return out, counts


def point_medians(v: np.ndarray, pt: np.ndarray, n: int) -> np.ndarray:
    """Per point, the median of the observations' values ``v [M]`` (``pt [M]`` the point of each), as numpy's (the
    mean of the two middle values for an even count): ``[n]``, NaN for a point without observations."""
    v, counts, starts = _sorted_by_point(v, pt, n)
    has = counts > 0
    out = np.full(n, np.nan)
    out[has] = (v[starts[has] + (counts[has] - 1) // 2] + v[starts[has] + counts[has] // 2]) / 2
    return out


def _sorted_by_point(v: np.ndarray, pt: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The values ``v [M]`` sorted by point (``pt [M]``) and by value within each, each point's count ``[n]`` and the
    index ``[n]`` where its values start."""
    counts = np.bincount(pt, minlength=n)
    return v[np.lexsort((v, pt))], counts, np.concatenate([[0], np.cumsum(counts)[:-1]])


def fit_points(R, t, p: BAProblem, iters: int = 6) -> torch.Tensor:
    """Best static point ``[N,3]`` of every track with the poses held fixed (Gauss-Newton on the same
    objective, offsets eliminated): used to test tracks that did not take part in the bundle adjustment. On a CPU
    in float32 (the static tests') by the compiled kernel :func:`trackingworld.optim.static_fit.fit_points`."""
    if COMPILED and R.device.type == "cpu" and R.dtype == torch.float32:
        return torch.from_numpy(static_fit.fit_points(_np(R), _np(t), *_problem_args(p), p.n_points, iters))
    X = init_points(R, t, p)
    eye = torch.eye(3, dtype=X.dtype, device=X.device)
    for _ in range(iters):
        _, Hxx, _, _, gx = _linearize(R, t, X, p, points_only=True)
        scale = torch.diagonal(Hxx, dim1=1, dim2=2).amax(-1).clamp_min(1e-30)[:, None, None]
        X = X - torch.linalg.solve(Hxx + 1e-6 * scale * eye, gx[..., None])[..., 0]
    return X
