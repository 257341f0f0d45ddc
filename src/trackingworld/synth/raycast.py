"""Exact ray casting of the scene's primitives and their procedural textures (numpy, CPU).

Rays are ``o + s * d`` with ``d`` the camera-frame direction ``K^-1 [x, y, 1]`` rotated to the world, so
the ray parameter ``s`` at a hit equals the camera-frame depth z.
"""

from __future__ import annotations

import numpy as np

from trackingworld.geometry import invert_pose, transform
from trackingworld.synth.scene import BOX, ROOM, SPHERE, Primitive, Scene

_EPS = 1e-9


def _intersect(p: Primitive, pose: np.ndarray, o: np.ndarray, d: np.ndarray):
    """Hit distance ``[M]`` (inf for a miss), local hit point ``[M,3]`` and local normal ``[M,3]``."""
    inv = invert_pose(pose)
    ol = transform(inv, o)
    dl = d @ inv[:3, :3].T
    M = d.shape[0]
    s = np.full(M, np.inf)
    normal = np.zeros((M, 3))
    if p.kind in (BOX, ROOM):
        h = p.size
        dsafe = np.where(np.abs(dl) < _EPS, _EPS, dl)
        t1 = (-h - ol) / dsafe
        t2 = (h - ol) / dsafe
        tmin_ax, tmax_ax = np.minimum(t1, t2), np.maximum(t1, t2)
        tmin, tmax = tmin_ax.max(1), tmax_ax.min(1)
        if p.kind == BOX:
            hit = (tmax >= tmin) & (tmin > 1e-6)
            s = np.where(hit, tmin, np.inf)
            ax = tmin_ax.argmax(1)
            normal[np.arange(M), ax] = -np.sign(dsafe[np.arange(M), ax])
        else:  # seen from inside: the exit point
            hit = tmax > 1e-6
            s = np.where(hit, tmax, np.inf)
            ax = tmax_ax.argmin(1)
            normal[np.arange(M), ax] = -np.sign(dsafe[np.arange(M), ax])
    elif p.kind == SPHERE:
        r = p.size[0]
        a = (dl * dl).sum(1)
        b = 2 * (ol * dl).sum(1)
        c = (ol * ol).sum(1) - r * r
        disc = b * b - 4 * a * c
        root = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
        s = np.where((disc >= 0) & (root > 1e-6), root, np.inf)
    local = ol + np.where(np.isfinite(s), s, 0)[:, None] * dl
    if p.kind == SPHERE:
        normal = local / max(p.size[0], _EPS)
    return s, local, normal


def cast(scene: Scene, t: int, o: np.ndarray, d: np.ndarray):
    """Cast rays ``o [M,3]``, ``d [M,3]`` (world) into frame ``t``.

    Returns hit parameter ``[M]`` (= camera depth for camera rays), primitive index ``[M]`` int,
    local hit point ``[M,3]`` and world normal ``[M,3]``.
    """
    M = d.shape[0]
    best = np.full(M, np.inf)
    idx = np.full(M, -1, dtype=np.int64)
    local = np.zeros((M, 3))
    normal = np.zeros((M, 3))
    for i, p in enumerate(scene.prims):
        s, lp, n = _intersect(p, p.poses[t], o, d)
        closer = s < best
        best = np.where(closer, s, best)
        idx[closer] = i
        local[closer] = lp[closer]
        normal[closer] = n[closer] @ p.poses[t][:3, :3].T
    return best, idx, local, normal


def camera_rays(scene: Scene, t: int, uv: np.ndarray):
    """World rays through pixels ``uv [M,2]`` of frame ``t`` (direction has camera z = 1)."""
    K = scene.K
    dc = np.stack([(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(uv))], 1)
    c2w = scene.poses_c2w[t]
    return np.broadcast_to(c2w[:3, 3], dc.shape), dc @ c2w[:3, :3].T


# ---------------------------------------------------------------- textures


def _value_noise(p: np.ndarray, seed: int) -> np.ndarray:
    """Trilinear value noise in [0,1] at points ``p [M,3]`` (lattice spacing 1), three channels ``[M,3]``."""
    rng = np.random.default_rng(seed)
    perm = rng.permutation(256)
    vals = rng.random((256, 3))
    pf = np.floor(p)
    f = p - pf
    f = f * f * (3 - 2 * f)  # smoothstep
    i = pf.astype(np.int64) & 255
    out = np.zeros((p.shape[0], 3))
    for dx in (0, 1):
        wx = f[:, 0] if dx else 1 - f[:, 0]
        hx = perm[(i[:, 0] + dx) & 255]
        for dy in (0, 1):
            wy = f[:, 1] if dy else 1 - f[:, 1]
            hy = perm[(hx + i[:, 1] + dy) & 255]
            for dz in (0, 1):
                wz = f[:, 2] if dz else 1 - f[:, 2]
                h = perm[(hy + i[:, 2] + dz) & 255]
                out += (wx * wy * wz)[:, None] * vals[h]
    return out


def texture(p: Primitive, local: np.ndarray) -> np.ndarray:
    """RGB in [0,1] ``[M,3]`` of points on primitive ``p`` given in its local frame (moves with it)."""
    q = local * p.tex_freq
    n = 0.55 * _value_noise(q, p.tex_seed) + 0.3 * _value_noise(2.7 * q + 17.0, p.tex_seed + 1)
    n += 0.15 * _value_noise(6.1 * q + 5.0, p.tex_seed + 2)
    lum = n.mean(1, keepdims=True)
    col = p.base_color[None] * (0.35 + 1.1 * lum) + 0.55 * (n - lum)
    return np.clip(col, 0, 1)


def shade(scene: Scene, idx: np.ndarray, local: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Textured, softly lit colour ``[M,3]`` in [0,1] for hits (black for misses)."""
    rgb = np.zeros((idx.shape[0], 3))
    light = np.array([0.3, -0.8, -0.4])
    light /= np.linalg.norm(light)
    lam = 0.8 + 0.2 * np.clip(normal @ light, 0, 1)
    for i, p in enumerate(scene.prims):
        m = idx == i
        if m.any():
            rgb[m] = texture(p, local[m]) * lam[m, None]
    return rgb
