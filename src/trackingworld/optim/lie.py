"""SE(3) and pinhole helpers on torch tensors, shared by the three optimisation stages.

Inside the optimiser poses are world-to-camera ``(R [...,3,3], t [...,3])``: a world point X is seen at
``Y = R X + t`` (OpenCV camera axes, metres). Updates are left perturbations ``xi = (omega, v)``:
``R <- exp(omega) R``, ``t <- exp(omega) t + v``, so that ``dY/dxi = [-[Y]x, I]``.
"""

from __future__ import annotations

import numpy as np
import torch


def skew(v: torch.Tensor) -> torch.Tensor:
    """``[...,3]`` -> cross-product matrices ``[...,3,3]``."""
    z = torch.zeros_like(v[..., 0])
    return torch.stack([
        torch.stack([z, -v[..., 2], v[..., 1]], -1),
        torch.stack([v[..., 2], z, -v[..., 0]], -1),
        torch.stack([-v[..., 1], v[..., 0], z], -1),
    ], -2)


def so3_exp(w: torch.Tensor) -> torch.Tensor:
    """Rotation vectors ``[...,3]`` (radians) -> rotation matrices ``[...,3,3]`` (Rodrigues, exact
    Taylor terms near zero so that autograd stays finite)."""
    th2 = (w * w).sum(-1, keepdim=True)[..., None]
    th = torch.sqrt(th2.clamp_min(1e-24))
    small = th2 < 1e-8
    a = torch.where(small, 1.0 - th2 / 6.0, torch.sin(th) / th)
    b = torch.where(small, 0.5 - th2 / 24.0, (1.0 - torch.cos(th)) / th2.clamp_min(1e-24))
    W = skew(w)
    eye = torch.eye(3, dtype=w.dtype, device=w.device).expand(W.shape)
    return eye + a * W + b * (W @ W)


def update(R: torch.Tensor, t: torch.Tensor, xi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Left-perturb world-to-camera poses by ``xi [...,6]`` = (rotation vector, translation)."""
    E = so3_exp(xi[..., :3])
    return E @ R, (E @ t[..., None])[..., 0] + xi[..., 3:]


def c2w_to_w2c(poses_c2w: np.ndarray, dtype=torch.float64, device="cpu") -> tuple[torch.Tensor, torch.Tensor]:
    """Camera-to-world ``[T,4,4]`` -> world-to-camera (R, t) tensors."""
    P = torch.as_tensor(np.asarray(poses_c2w), dtype=dtype, device=device)
    R = P[:, :3, :3].transpose(1, 2)
    return R.contiguous(), -(R @ P[:, :3, 3:])[..., 0]


def w2c_to_c2w(R: torch.Tensor, t: torch.Tensor) -> np.ndarray:
    """World-to-camera (R, t) -> camera-to-world ``[T,4,4]`` float64 numpy."""
    Rc = R.transpose(-1, -2)
    out = torch.zeros(R.shape[:-2] + (4, 4), dtype=R.dtype, device=R.device)
    out[..., :3, :3] = Rc
    out[..., :3, 3] = -(Rc @ t[..., None])[..., 0]
    out[..., 3, 3] = 1.0
    return out.detach().cpu().numpy().astype(np.float64)


def transform(R: torch.Tensor, t: torch.Tensor, X: torch.Tensor) -> torch.Tensor:
    """``R X + t`` with broadcasting: R ``[...,3,3]``, t and X ``[...,3]``."""
    return (R @ X[..., None])[..., 0] + t


def project(Y: torch.Tensor, K: torch.Tensor, min_z: float = 1e-3) -> torch.Tensor:
    """Camera points ``[...,3]`` -> pixels ``[...,2]`` (depth clamped at ``min_z`` for the division)."""
    z = Y[..., 2].clamp_min(min_z)
    return torch.stack([K[0, 0] * Y[..., 0] / z + K[0, 2], K[1, 1] * Y[..., 1] / z + K[1, 2]], -1)


def project_jacobian(Y: torch.Tensor, K: torch.Tensor, min_z: float = 1e-3) -> torch.Tensor:
    """d pixel / d Y ``[...,2,3]`` of :func:`project`."""
    z = Y[..., 2].clamp_min(min_z)
    zero = torch.zeros_like(z)
    fx, fy = K[0, 0], K[1, 1]
    return torch.stack([
        torch.stack([fx / z, zero, -fx * Y[..., 0] / z**2], -1),
        torch.stack([zero, fy / z, -fy * Y[..., 1] / z**2], -1),
    ], -2)


def unproject(uv: torch.Tensor, depth: torch.Tensor, K: torch.Tensor) -> torch.Tensor:
    """Pixels ``[...,2]`` and camera depths ``[...]`` -> camera points ``[...,3]``."""
    return torch.stack([(uv[..., 0] - K[0, 2]) / K[0, 0] * depth, (uv[..., 1] - K[1, 2]) / K[1, 1] * depth,
                        depth], -1)


def pose_jacobian(Y: torch.Tensor) -> torch.Tensor:
    """dY / dxi ``[...,3,6]`` for a left perturbation of the pose that maps to Y."""
    eye = torch.eye(3, dtype=Y.dtype, device=Y.device).expand(Y.shape[:-1] + (3, 3))
    return torch.cat([-skew(Y), eye], -1)
