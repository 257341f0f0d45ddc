"""Camera geometry on numpy arrays: projection, unprojection and pose helpers.

Conventions: OpenCV camera axes, camera-to-world 4x4 poses, pixel centres at integer coordinates.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def intrinsics_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """Return the 3x3 pinhole matrix."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=np.float64)


def default_intrinsics(width: int, height: int, fov_deg: float = 60.0) -> np.ndarray:
    """Intrinsics with a horizontal field of view ``fov_deg`` and the principal point at the image centre."""
    f = 0.5 * width / np.tan(np.deg2rad(fov_deg) / 2)
    return intrinsics_matrix(f, f, (width - 1) / 2.0, (height - 1) / 2.0)


def scale_intrinsics(K: np.ndarray, sx: float, sy: float) -> np.ndarray:
    """Intrinsics for an image resized by (sx, sy), keeping pixel-centre conventions exact."""
    K2 = np.array(K, dtype=np.float64).copy()
    K2[0, 0] *= sx
    K2[1, 1] *= sy
    K2[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
    K2[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    return K2


def unproject(uv: np.ndarray, depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pixels ``[...,2]`` with depths ``[...]`` (camera z, metres) -> camera points ``[...,3]``."""
    x = (uv[..., 0] - K[0, 2]) / K[0, 0]
    y = (uv[..., 1] - K[1, 2]) / K[1, 1]
    return np.stack([x * depth, y * depth, depth], axis=-1)


def focal_length(K: np.ndarray) -> float:
    """One focal length (px) of K ``[3,3]``: the geometric mean of fx and fy."""
    return float(np.sqrt(K[0, 0] * K[1, 1]))


def nearest_pixel(uv: np.ndarray, W: int, H: int) -> tuple[np.ndarray, np.ndarray]:
    """Integer (x [M], y [M]) of the pixel nearest to ``uv`` [M,2], clamped to a W x H image."""
    x = np.clip(np.rint(uv[:, 0]).astype(np.int64), 0, W - 1)
    y = np.clip(np.rint(uv[:, 1]).astype(np.int64), 0, H - 1)
    return x, y


def in_image(uv: np.ndarray, W: int, H: int, margin: float = 0.0) -> np.ndarray:
    """Whether pixels ``uv [M,2]`` lie in a W x H image, at least ``margin`` px inside its edge [M] bool. Pixel
    centres are at integers, so the image's edge is at -0.5 and W - 0.5 (H - 0.5); margin 0.5 keeps the pixels
    that can be sampled bilinearly, from 0 to W - 1. The bounds are included."""
    lo = margin - 0.5
    return ((uv[:, 0] >= lo) & (uv[:, 0] <= W - 0.5 - margin)
            & (uv[:, 1] >= lo) & (uv[:, 1] <= H - 0.5 - margin))


def project(xyz_cam: np.ndarray, K: np.ndarray, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Camera points ``[...,3]`` -> (pixels ``[...,2]``, depth ``[...]``). Depth is clamped at ``eps``
    for the division only, so points behind the camera give finite pixels."""
    z = xyz_cam[..., 2]
    zs = np.where(np.abs(z) < eps, eps, z)
    u = K[0, 0] * xyz_cam[..., 0] / zs + K[0, 2]
    v = K[1, 1] * xyz_cam[..., 1] / zs + K[1, 2]
    return np.stack([u, v], axis=-1), z


def transform(T: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply 4x4 transforms ``[...,4,4]`` to points ``[...,3]`` (broadcasting)."""
    # a column of R at a time: with one pose per frame broadcast over the tracks ([T,4,4] against [N,T,3]) this is
    # 2.5x faster than einsum, which does not use BLAS for broadcast operands (0.37 against 0.94 s at 38,800 x 120)
    R = T[..., :3, :3]
    out = pts[..., 0:1] * R[..., :, 0]
    out += pts[..., 1:2] * R[..., :, 1]
    out += pts[..., 2:3] * R[..., :, 2]
    out += T[..., :3, 3]
    return out


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Invert rigid 4x4 transforms ``[...,4,4]``."""
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    out = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


def camera_depths(xyz_world: np.ndarray, poses_c2w: np.ndarray) -> np.ndarray:
    """World tracks ``[N,T,3]`` -> camera z ``[N,T]`` in each frame of the camera-to-world ``poses_c2w [T,4,4]``."""
    return depth_along(xyz_world, invert_pose(poses_c2w)[:, 2])  # [T,4] the world-to-camera row of z


def depth_along(points: np.ndarray, row: np.ndarray) -> np.ndarray:
    """Camera z ``[...]`` of world ``points [...,3]`` under world-to-camera z rows ``row [...,4]`` (broadcast):
    ``x r0 + y r1 + z r2 + r3``, in that order (so a subset's depths are the whole array's to the bit)."""
    return points[..., 0] * row[..., 0] + points[..., 1] * row[..., 1] + points[..., 2] * row[..., 2] + row[..., 3]


def rigid_transform(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The 4x4 rigid transform taking points ``a [n,3]`` to ``b [n,3]`` in the least-squares sense (Kabsch)."""
    ma, mb = a.mean(0), b.mean(0)
    U, _, Vt = np.linalg.svd((b - mb).T @ (a - ma))
    R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = R, mb - R @ ma
    return out


def pose_from_rt(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Build ``[...,4,4]`` poses from rotations ``[...,3,3]`` and translations ``[...,3]``."""
    shape = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros(shape + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """Camera-to-world pose at ``eye`` looking at ``target``; ``up`` is the world's up (default -y: y down)."""
    up = np.array([0.0, -1.0, 0.0]) if up is None else up
    z = target - eye
    z = z / np.linalg.norm(z)
    x = np.cross(z, up)  # OpenCV: x right = forward x up
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    return pose_from_rt(np.stack([x, y, z], axis=1), eye)


def rotation_angle_deg(R: np.ndarray) -> np.ndarray:
    """Rotation angle in degrees of rotation matrices ``[...,3,3]``."""
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.rad2deg(np.arccos(np.clip(c, -1.0, 1.0)))


def quat_wxyz(R: np.ndarray) -> np.ndarray:
    """Unit quaternions ``[...,4]`` (w, x, y, z) of rotation matrices ``[...,3,3]``."""
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()  # x, y, z, w
    q = np.concatenate([q[:, 3:], q[:, :3]], axis=1)
    return q.reshape(R.shape[:-2] + (4,))
