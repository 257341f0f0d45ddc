"""Reading input frames: a video file (through PyAV) or a folder of images (sorted by name)."""

from __future__ import annotations

import os
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from trackingworld.errors import InputError

IMAGE_EXTS = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp"}
VIDEO_EXTS = {".mp4", ".mov", ".avi", ".mkv", ".webm", ".m4v", ".gif"}


def list_images(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTS)


def read_image(path: Path) -> np.ndarray:
    """One image file (a frame, a mask or a depth PNG) as imageio reads it, or an :class:`InputError` naming it
    where it is not an image, damaged or cut short: imageio hands a file no image plugin takes to PyAV, which reads
    no frame from it ("need at least one array to stack"), and Pillow calls some broken PNGs a SyntaxError."""
    try:
        return iio.imread(path)
    except (OSError, ValueError, RuntimeError, SyntaxError) as e:
        why = "no image in it" if "at least one array" in str(e) else str(e) or type(e).__name__
        raise InputError(f"{path}: cannot read image: not an image, damaged or cut short ({why})") from e


def _to_rgb(img: np.ndarray, src: Path) -> np.ndarray:
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        raise InputError(f"{src}: unsupported image layout {img.shape}")
    img = img[..., :3]
    if img.dtype == np.uint16:
        img = (img // 257).astype(np.uint8)
    elif img.dtype != np.uint8:
        img = np.clip(img, 0, 255).astype(np.uint8)
    return img


def read_frames(
    path: str | os.PathLike, max_frames: int | None = None, stride: int = 1
) -> tuple[np.ndarray, float | None]:
    """Read frames ``[T,H,W,3]`` uint8 RGB and the frame rate (None for image folders).

    ``stride`` keeps every k-th frame, ``max_frames`` caps the count after striding.
    """
    path = Path(path)
    if stride < 1:
        raise InputError(f"--frame-stride must be >= 1, got {stride}")
    if not path.exists():
        raise InputError(f"{path}: no such file or folder")
    frames: list[np.ndarray] = []
    fps = None
    if path.is_dir():
        files = list_images(path)[::stride]
        if max_frames:
            files = files[:max_frames]
        if not files:
            raise InputError(f"{path}: folder holds no images ({', '.join(sorted(IMAGE_EXTS))})")
        for f in files:
            frames.append(_to_rgb(read_image(f), f))
    else:
        if path.suffix.lower() not in VIDEO_EXTS and path.suffix.lower() not in IMAGE_EXTS:
            raise InputError(f"{path}: unknown input type (expected a video file or a folder of images)")
        try:
            meta = iio.immeta(path, plugin="pyav") if path.suffix.lower() in VIDEO_EXTS else {}
            fps = meta.get("fps")
            for i, img in enumerate(iio.imiter(path, plugin="pyav") if path.suffix.lower() in VIDEO_EXTS
                                    else [iio.imread(path)]):
                if i % stride:
                    continue
                frames.append(_to_rgb(np.asarray(img), path))
                if max_frames and len(frames) >= max_frames:
                    break
        except InputError:
            raise
        except Exception as e:  # PyAV raises many types for broken files
            raise InputError(f"{path}: cannot decode video ({type(e).__name__}: {e})") from e
        if not frames:
            raise InputError(f"{path}: video holds no frames")
    shapes = {f.shape for f in frames}
    if len(shapes) != 1:
        raise InputError(f"{path}: frames differ in size ({sorted(shapes)})")
    return np.stack(frames), (float(fps) / stride if fps else None)


def frames_for_result(result_dir: str | os.PathLike, shape: tuple[int, int, int],
                      video: str | os.PathLike | None = None) -> tuple[np.ndarray | None, str]:
    """The input frames ``[T,H,W,3]`` of a result folder, read again from the input named in its
    ``config.json`` (or from ``video``), with the run's frame stride and cap.

    ``shape`` is the result's (T, H, W). Returns (frames, "") or (None, why not) when the input has moved or
    does not match the result: callers fall back to the tracks' own colours."""
    import json

    result_dir = Path(result_dir)
    stride, cap = 1, None
    cfg_path = result_dir / "config.json"
    if cfg_path.exists():
        try:
            inputs = json.loads(cfg_path.read_text()).get("inputs", {})
        except (OSError, ValueError):
            inputs = {}
        stride, cap = int(inputs.get("frame_stride") or 1), inputs.get("max_frames")
        if video is None and inputs.get("input"):
            video = Path(inputs["input"])
            if not video.is_absolute() and not video.exists():
                video = result_dir / video
    if video is None:
        return None, f"{cfg_path}: no input recorded"
    try:
        frames, _ = read_frames(video, cap or shape[0], stride)
    except InputError as e:
        return None, str(e)
    if frames.shape[:3] != tuple(shape):
        return None, f"{video}: frames {frames.shape[:3]} do not match the result's {tuple(shape)}"
    return frames, ""
