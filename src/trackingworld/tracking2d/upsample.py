"""Sparse-to-dense upsampling of grid tracks (paper Sec. 3.2, weight-free).

Every dense pixel takes a convex combination of the displacements of the 5x5 grid tracks around it. The
weights are computed once, at the query frame, from spatial distance, colour similarity and similarity of
motion (the pixel's displacement over a window of frames against each neighbour's, see
``DenseConfig.motion_window``), and applied to displacements and visibility at every frame. Neighbours outside
the image or not tracked get no weight.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch


@dataclass
class UpsampleConfig:
    radius: int = 2  # 5x5 neighbourhood
    sigma_space: float = 1.0  # in grid cells
    sigma_color: float = 0.08  # RGB in [0,1]
    sigma_motion: float = 0.75  # pixels of flow difference
    mode: str = "convex"  # convex | bilinear
    top_k: int = 16  # keep the k largest weights of each pixel (renormalised); 0: all (2 radius + 1)^2
    # first-order correction (not in the paper): the displacement is the weighted local affine fit of the
    # neighbours' displacements evaluated at the pixel, not their weighted mean, which is off by the flow's
    # gradient times the offset of the weights' centroid from the pixel (colour weights put it anywhere in
    # the 5x5 cells); ridge (px^2) on the neighbours' spread keeps one-sided or collinear sets near the mean.
    # affine_ridge < 0: off (the weighted mean alone, as the paper's convex upsampler)
    affine_ridge: float = 0.1


def grid_offset(stride: int) -> float:
    return (stride - 1) / 2.0


def neighbour_weights(pix: np.ndarray, grid_shape: tuple[int, int], stride: int, image: np.ndarray,
                      motion: np.ndarray | None, grid_ok: np.ndarray, cfg: UpsampleConfig):
    """Indices ``[M,K]`` into the flattened grid and convex weights ``[M,K]`` for pixels ``pix [M,2]``.

    image [H,W,3] float in [0,1] at the query frame; motion [H,W,C] per-pixel motion features (displacements
    over a window of frames) or None; grid_ok [gh,gw] bool: grid tracks that exist.
    """
    gh, gw = grid_shape
    H, W = image.shape[:2]
    off = grid_offset(stride)
    gx = (pix[:, 0] - off) / stride
    gy = (pix[:, 1] - off) / stride
    if cfg.mode == "bilinear":
        x0, y0 = np.floor(gx).astype(int), np.floor(gy).astype(int)
        dx, dy = gx - x0, gy - y0
        ix = np.stack([x0, x0 + 1, x0, x0 + 1], 1)
        iy = np.stack([y0, y0, y0 + 1, y0 + 1], 1)
        w = np.stack([(1 - dx) * (1 - dy), dx * (1 - dy), (1 - dx) * dy, dx * dy], 1)
        ok = (ix >= 0) & (ix < gw) & (iy >= 0) & (iy < gh)
        ok[ok] &= grid_ok[iy[ok], ix[ok]]
        w = np.where(ok, w, 0.0)
    else:
        r = cfg.radius
        offs = np.arange(-r, r + 1)
        cx, cy = np.round(gx).astype(int), np.round(gy).astype(int)
        ix = (cx[:, None, None] + offs[None, None, :]).repeat(len(offs), 1).reshape(len(pix), -1)
        iy = (cy[:, None, None] + offs[None, :, None]).repeat(len(offs), 2).reshape(len(pix), -1)
        ok = (ix >= 0) & (ix < gw) & (iy >= 0) & (iy < gh)
        ixc, iyc = ix.clip(0, gw - 1), iy.clip(0, gh - 1)
        ok &= grid_ok[iyc, ixc]
        # appearance and motion features scaled by their sigmas, read at the grid nodes (the integer pixel
        # nearest to each node centre) and at the pixels; one gather of [M,K,C] float32
        feats = [image / cfg.sigma_color] + ([motion / cfg.sigma_motion] if motion is not None else [])
        feat = np.concatenate(feats, -1).astype(np.float32) / np.float32(np.sqrt(2.0))
        nodes_x = np.clip(np.round(off + np.arange(gw) * stride).astype(int), 0, W - 1)
        nodes_y = np.clip(np.round(off + np.arange(gh) * stride).astype(int), 0, H - 1)
        node_feat = feat[nodes_y][:, nodes_x].reshape(gh * gw, -1)
        px = np.clip(np.round(pix[:, 0]).astype(int), 0, W - 1)
        py = np.clip(np.round(pix[:, 1]).astype(int), 0, H - 1)
        diff = node_feat[iyc * gw + ixc] - feat[py, px][:, None]
        s2 = np.float32(2 * cfg.sigma_space**2)
        d2 = ((gx[:, None] - ixc.astype(np.float32)) ** 2 + (gy[:, None] - iyc.astype(np.float32)) ** 2) / s2
        logit = -(d2 + np.einsum("mkc,mkc->mk", diff, diff))
        logit = np.where(ok, logit, -np.inf)
        mx = logit.max(1, keepdims=True)
        mx = np.where(np.isfinite(mx), mx, 0.0)
        w = np.where(ok, np.exp(logit - mx), 0.0)
    idx = (iy.clip(0, gh - 1) * gw + ix.clip(0, gw - 1)).astype(np.int64)
    if 0 < cfg.top_k < w.shape[1]:
        keep = np.argpartition(-w, cfg.top_k - 1, axis=1)[:, : cfg.top_k]
        w, idx = np.take_along_axis(w, keep, 1), np.take_along_axis(idx, keep, 1)
    s = w.sum(1, keepdims=True)
    w = np.where(s > 0, w / np.maximum(s, 1e-12), 0.0)
    return idx, w.astype(np.float32)


def apply_weights(pix: np.ndarray, idx: np.ndarray, w: np.ndarray, grid_tracks: np.ndarray, grid_vis: np.ndarray,
                  t_query: int, device: str = "cpu", chunk: int = 16384, affine_ridge: float = -1.0):
    """Dense tracks ``[M,T,2]`` and visibility weight ``[M,T]`` (pixels) from grid tracks ``[G,T,2]`` /
    ``[G,T]`` and the neighbours ``idx [M,K]`` / weights ``w [M,K]`` of the pixels ``pix [M,2]`` at frame
    ``t_query``. ``affine_ridge`` >= 0: first-order correction, see :class:`UpsampleConfig`."""
    dev = torch.device(device)
    gt = torch.as_tensor(grid_tracks, dtype=torch.float32, device=dev)
    disp = gt - gt[:, t_query : t_query + 1]
    gv = torch.as_tensor(grid_vis, dtype=torch.float32, device=dev)
    M, T = len(pix), grid_tracks.shape[1]
    out = np.empty((M, T, 2), np.float32)
    vis = np.empty((M, T), np.float32)
    first_order = affine_ridge >= 0
    for a in range(0, M, chunk):
        b = min(a + chunk, M)
        i = torch.as_tensor(idx[a:b], device=dev)
        ww = torch.as_tensor(w[a:b], device=dev)
        di = disp[i]  # [m,K,T,2]
        m, K = i.shape
        wv = ww[..., None] * gv[i]  # [m,K,T]: weights of the neighbours visible in each frame
        sv = wv.sum(1)  # [m,T]
        p = torch.as_tensor(pix[a:b], dtype=torch.float32, device=dev)[:, None]
        # weighted moments of the displacements over the neighbours, one batched product: [m,T,2,E] with
        # E = 1 (sum of w d) or 3 (sums of w d, w d rx, w d ry; r = neighbour minus pixel at the query frame)
        rel = gt[i, t_query] - p  # [m,K,2]
        basis = torch.cat([torch.ones_like(rel[..., :1]), rel], -1) if first_order else rel.new_ones(m, K, 1)
        wd = (wv[..., None] * di).reshape(m, K, T * 2).transpose(1, 2)  # [m,2T,K]
        mom = torch.bmm(wd, basis).reshape(m, T, 2, -1)
        inv = 1.0 / sv.clamp_min(1e-6)  # [m,T]
        # positions from the visible neighbours only (an occluded neighbour's position is a guess);
        # where none is visible, from all of them
        d_vis = mom[..., 0] * inv[..., None]
        if first_order:
            d_vis = d_vis - _gradient_term(rel, wv, inv, d_vis, mom[..., 1:] * inv[..., None, None], affine_ridge)
        d_all = torch.einsum("mk,mktc->mtc", ww, di)
        d = torch.where((sv > 1e-6)[..., None], d_vis, d_all)  # [m,T,2]
        out[a:b] = (p + d).cpu().numpy()
        vis[a:b] = sv.cpu().numpy()
    return out, vis


def _gradient_term(rel: torch.Tensor, wv: torch.Tensor, inv: torch.Tensor, dbar: torch.Tensor,
                   dx: torch.Tensor, ridge: float) -> torch.Tensor:
    """What to subtract from the weighted mean displacement ``dbar [m,T,2]`` to evaluate the weighted affine fit
    at the pixel: C xbar, with xbar ``[m,T,2]`` the weighted centroid of the neighbours' offsets ``rel [m,K,2]``
    (px, neighbour minus pixel, at the query frame) and C = Cov(d, x) (Cov(x, x) + ridge I)^-1 ``[m,T,2,2]``;
    ``wv [m,K,T]``: the per-frame weights, ``inv [m,T]`` one over their sums, ``dx [m,T,2,2]`` the weighted
    means of d_c x_e. Written out for 2x2 matrices (no batched solve)."""
    x2 = torch.stack([rel[..., 0], rel[..., 1], rel[..., 0] ** 2, rel[..., 0] * rel[..., 1], rel[..., 1] ** 2], -1)
    mx = torch.bmm(wv.transpose(1, 2), x2) * inv[..., None]  # [m,T,5]: weighted means of x, y, xx, xy, yy
    xbar = mx[..., :2]
    sdx = dx - dbar[..., :, None] * xbar[..., None, :]
    # at least 0.01 px^2: a spread of float32 rounding (neighbours' weights on one node) must not make a gradient
    ridge = max(ridge, 1e-2)
    a = mx[..., 2] - xbar[..., 0] ** 2 + ridge
    b = mx[..., 3] - xbar[..., 0] * xbar[..., 1]
    c = mx[..., 4] - xbar[..., 1] ** 2 + ridge
    det = (a * c - b * b).clamp_min(1e-12)
    # C xbar = sdx (sxx + ridge I)^-1 xbar
    y0 = (c * xbar[..., 0] - b * xbar[..., 1]) / det
    y1 = (a * xbar[..., 1] - b * xbar[..., 0]) / det
    return sdx[..., 0] * y0[..., None] + sdx[..., 1] * y1[..., None]
