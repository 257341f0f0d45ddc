"""Reading user-given priors: depth maps, dynamic masks and intrinsics."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from trackingworld.errors import InputError
from trackingworld.io.arrays import read_array
from trackingworld.io.frames import list_images, read_image


def _select(arr: np.ndarray, T_video: int, stride: int, path: Path, what: str) -> np.ndarray:
    """Apply the same frame stride / cap as the video and check the frame count."""
    arr = arr[::stride]
    if arr.shape[0] < T_video:
        raise InputError(f"{path}: {what} has {arr.shape[0]} frames after stride {stride}, video has {T_video}")
    return arr[:T_video]


def load_depth(path: str | os.PathLike, T: int, stride: int = 1) -> np.ndarray:
    """Depth ``[T,H,W]`` float32 metres from ``.npy``/``.npz`` (metres) or a folder of 16-bit PNGs (mm)."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such depth file or folder")
    if path.is_dir():
        files = list_images(path)
        if not files:
            raise InputError(f"{path}: depth folder holds no PNG files")
        imgs = []
        for f in files[::stride][:T]:
            d = read_image(f)
            if d.dtype != np.uint16 or d.ndim != 2:
                raise InputError(f"{f}: depth PNG must be single-channel 16-bit millimetres, got {d.dtype} {d.shape}")
            imgs.append(d.astype(np.float32) / 1000.0)
        depth = np.stack(imgs)
        if depth.shape[0] < T:
            raise InputError(f"{path}: depth folder has {depth.shape[0]} usable frames, video has {T}")
    else:
        if path.suffix not in (".npy", ".npz"):
            raise InputError(f"{path}: depth must be .npy, .npz or a folder of 16-bit PNGs")
        depth = read_array(path, "depth", "depth")
        if not np.issubdtype(depth.dtype, np.floating):  # millimetres in an integer array? not guessed
            raise InputError(f"{path}: depth holds {depth.dtype} numbers; give float metres (or a folder of 16-bit "
                             f"PNGs in millimetres)")
        if depth.ndim == 4 and depth.shape[1] == 1:
            depth = depth[:, 0]
        if depth.ndim != 3:
            raise InputError(f"{path}: depth must be [T,H,W], got shape {depth.shape}")
        depth = _select(depth.astype(np.float32), T, stride, path, "depth")
    bad = ~np.isfinite(depth)
    if bad.all():
        raise InputError(f"{path}: depth holds no finite values")
    if (depth[~bad] <= 0).all():
        raise InputError(f"{path}: depth holds no positive values")
    return depth


def fill_invalid_depth(depth: np.ndarray) -> np.ndarray:
    """``[T,H,W]`` float32 with non-finite and non-positive values replaced by the median of the valid ones."""
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan).astype(np.float32)
    return np.nan_to_num(depth, nan=np.nanmedian(depth))


def load_masks(path: str | os.PathLike, T: int, stride: int = 1) -> np.ndarray:
    """Dynamic masks ``[T,H,W]`` bool from a folder of PNGs (non-zero = dynamic) or a ``.npy`` bool array."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such mask file or folder")
    if path.is_dir():
        files = list_images(path)[::stride][:T]
        if len(files) < T:
            raise InputError(f"{path}: mask folder has {len(files)} usable images, video has {T}")
        masks = []
        for f in files:
            m = read_image(f)
            masks.append((m.max(axis=-1) if m.ndim == 3 else m) > 0)
        return np.stack(masks)
    if path.suffix not in (".npy", ".npz"):
        raise InputError(f"{path}: masks must be a folder of PNGs or a .npy array")
    m = read_array(path, "masks", "masks")
    if m.ndim != 3:
        raise InputError(f"{path}: masks must be [T,H,W], got shape {m.shape}")
    return _select(m != 0, T, stride, path, "masks")


def parse_intrinsics(spec: str | os.PathLike) -> np.ndarray:
    """Intrinsics from a text file (3x3 matrix or ``fx,fy,cx,cy``) or an inline ``fx,fy,cx,cy`` string."""
    text = str(spec)
    p = Path(text)
    src = text
    if p.exists():
        src = str(p)
        text = p.read_text()
    vals = [v for v in text.replace(",", " ").split() if v]
    try:
        nums = np.array([float(v) for v in vals])
    except ValueError as e:
        raise InputError(f"{src}: intrinsics must be a 3x3 matrix or fx,fy,cx,cy ({e})") from e
    if nums.size == 9:
        K = nums.reshape(3, 3)
    elif nums.size == 4:
        fx, fy, cx, cy = nums
        K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    else:
        raise InputError(f"{src}: intrinsics must hold 9 numbers (3x3) or 4 (fx,fy,cx,cy), found {nums.size}")
    if not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise InputError(f"{src}: intrinsics need positive finite focal lengths")
    if not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:  # a pinhole camera's matrix: the stages read fx, fy, cx, cy
        raise InputError(f"{src}: intrinsics must be upper triangular with last row 0 0 1, got {K.tolist()}")
    return K


# how far a prior's width / height may differ from the frames' and be stretched to them without a word: a depth
# model's output rounded to its patch size (854x480 frames, 518x294 depth: 1.0%)
ASPECT_TOLERANCE = 0.02


def prior_fit(shape: tuple[int, ...], W: int, H: int, path, what: str) -> str | None:
    """How a prior of ``shape [T,Hp,Wp]`` (depth maps, masks) goes onto frames of W x H px: None where it has their
    size or their aspect ratio (resized); a warning (str) where its aspect ratio differs by more than
    :data:`ASPECT_TOLERANCE` (stretched to fit: right for a model run on frames squeezed to its own size, wrong for
    a crop or a pad); InputError where its height and width are the frames' swapped (a rotated or transposed array,
    which a resize would smear over the frames)."""
    Hp, Wp = shape[-2:]
    if (Hp, Wp) == (H, W):
        return None
    if (Hp, Wp) == (W, H):
        raise InputError(f"{path}: {what} of {Wp}x{Hp} px for frames of {W}x{H}: height and width swapped (a rotated "
                         f"or transposed array?)")
    if abs(np.log((Wp / Hp) / (W / H))) > np.log1p(ASPECT_TOLERANCE):
        return (f"{path}: {what} of {Wp}x{Hp} px, another aspect ratio than the {W}x{H} frames' ({Wp / Hp:.3f} against "
                f"{W / H:.3f}): stretched to fit them; if it was cropped or padded, its pixels are misplaced")
    return None


def check_principal_point(K: np.ndarray, W: int, H: int, src) -> None:
    """InputError where the principal point of ``K [3,3]`` lies outside the frames of W x H px: intrinsics of another
    resolution (a calibration of the full-size video given for a smaller one), which would bend every ray."""
    cx, cy = float(K[0, 2]), float(K[1, 2])
    if not (0 <= cx <= W and 0 <= cy <= H):
        raise InputError(f"{src}: the principal point ({cx:g}, {cy:g}) px lies outside the {W}x{H} frames: "
                         f"intrinsics of another resolution? Give them for the video's own size")
