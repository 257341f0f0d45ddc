"""Depth priors from pretrained models: Hugging Face ``transformers`` depth estimators and UniDepth.

Nothing is downloaded unless the user names a hub model; a local folder written by ``save_pretrained`` (or a
hub id already in the local cache) loads offline. Every model returns a :class:`DepthPrediction`:

- ``metric``: depth in metres (Depth Anything V2 Metric, ZoeDepth, Depth Pro, UniDepth);
- ``disparity``: relative inverse depth, known only up to an affine map (Depth Anything V2, DPT); turned into
  depth by :mod:`trackingworld.priors.align`.

Depth Pro and UniDepth also estimate the focal length, used when the user gave no intrinsics.
"""

from __future__ import annotations

import inspect
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from trackingworld.errors import InputError
from trackingworld.geometry import focal_length

# short names for the well-known checkpoints (any hub id or local folder works too)
DEPTH_MODELS = {
    "depth-anything-v2-small": "depth-anything/Depth-Anything-V2-Small-hf",
    "depth-anything-v2-base": "depth-anything/Depth-Anything-V2-Base-hf",
    "depth-anything-v2-large": "depth-anything/Depth-Anything-V2-Large-hf",
    "depth-anything-v2-metric-indoor": "depth-anything/Depth-Anything-V2-Metric-Indoor-Small-hf",
    "depth-anything-v2-metric-outdoor": "depth-anything/Depth-Anything-V2-Metric-Outdoor-Small-hf",
    "depth-pro": "apple/DepthPro-hf",
    "zoedepth": "Intel/zoedepth-nyu-kitti",
    "unidepth": "unidepth:lpiccinelli/unidepth-v2-vits14",
}
METRIC_TYPES = {"zoedepth", "depth_pro"}  # model types whose output is metric depth


@dataclass
class DepthPrediction:
    values: np.ndarray  # [T,H,W] float32: metres (metric) or relative inverse depth (disparity)
    kind: str  # "metric" | "disparity"
    focal_px: float | None = None  # at the frames' resolution, when the model estimates it
    source: str = ""


def is_model_spec(spec: str) -> bool:
    """True when ``spec`` names a depth model (short name, ``hf:ID``, ``unidepth:ID``, or a folder holding a
    ``config.json``) rather than a depth file."""
    p = Path(spec)
    if spec in DEPTH_MODELS or spec.startswith(("hf:", "unidepth:")):
        return True
    return p.is_dir() and (p / "config.json").exists()


def _model_type(model) -> str:
    return getattr(model.config, "model_type", "")


def _kind(model) -> str:
    if getattr(model.config, "depth_estimation_type", "relative") == "metric" or _model_type(model) in METRIC_TYPES:
        return "metric"
    return "disparity"


class HFDepthModel:
    """A ``transformers`` depth estimator (``AutoModelForDepthEstimation`` + its image processor)."""

    def __init__(self, name: str, device: str = "cpu", batch_size: int = 4):
        try:
            from transformers import AutoImageProcessor, AutoModelForDepthEstimation
        except ImportError as e:
            raise InputError(f"{name}: depth models need transformers (pip install 'trackingworld[models]')") from e
        local = Path(name).is_dir()
        try:
            self.model = AutoModelForDepthEstimation.from_pretrained(name, local_files_only=local).to(device).eval()
            try:
                self.processor = AutoImageProcessor.from_pretrained(name, local_files_only=local)
            except (ImportError, ValueError):  # a processor that needs torchvision, which has no CPU build
                if _model_type(self.model) != "depth_pro":
                    raise
                self.processor = DepthProProcessor.from_pretrained(name, local)
        except (OSError, ValueError) as e:
            raise InputError(f"{name}: cannot load the depth model ({str(e).splitlines()[0]}); models download from "
                             "the Hugging Face hub on first use, or give a local folder") from e
        self.name, self.device, self.batch_size = name, device, batch_size
        self.kind = _kind(self.model)

    @torch.no_grad()
    def predict(self, frames: np.ndarray, verbose: bool = True) -> DepthPrediction:
        """frames [T,H,W,3] uint8 RGB -> depth or disparity at the frames' resolution."""
        T, H, W = frames.shape[:3]
        out = np.zeros((T, H, W), np.float32)
        focals = []
        post = self.processor.post_process_depth_estimation
        params = inspect.signature(post).parameters
        for s in range(0, T, self.batch_size):
            imgs = list(frames[s:s + self.batch_size])
            inputs = self.processor(images=imgs, return_tensors="pt").to(self.device)
            outputs = self.model(**inputs)
            kw = {"target_sizes": [(H, W)] * len(imgs)}
            if "source_sizes" in params:  # ZoeDepth removes its padding with the source sizes
                kw["source_sizes"] = [(H, W)] * len(imgs)
            try:
                results = post(outputs, **kw)
            except (NameError, ImportError):  # a processor whose post-processing needs torchvision (none here)
                if getattr(outputs, "field_of_view", None) is not None:  # Depth Pro: not a plain resize
                    raise
                results = _post_process_plain(outputs, H, W, _model_type(self.model) == "zoedepth"
                                              and getattr(self.processor, "do_pad", False))
            for i, r in enumerate(results):
                out[s + i] = r["predicted_depth"].float().cpu().numpy()
                f = r.get("focal_length")
                if f is not None and np.isfinite(float(f)) and float(f) > 0:  # a broken estimate is not used
                    focals.append(float(f))
            if verbose:
                print(f"[depth] {self.name}: {min(s + len(imgs), T)}/{T} frames", file=sys.stderr, flush=True)
        focal = float(np.median(focals)) if focals else None
        return DepthPrediction(out, self.kind, focal, self.name)


class DepthProProcessor:
    """Depth Pro's pre- and post-processing without torchvision (``transformers``' DepthProImageProcessor needs
    it, and torchvision has no CPU build here). The same steps: rescale and normalise, then a bilinear resize
    without antialiasing to the model's square input; back at the frame size, the canonical inverse depth times
    ``W / f`` (f from the predicted field of view) inverted to metres."""

    def __init__(self, size: dict, mean, std, rescale_factor: float = 1 / 255):
        self.size = (int(size["height"]), int(size["width"]))
        self.mean = torch.as_tensor(mean, dtype=torch.float32)[:, None, None]
        self.std = torch.as_tensor(std, dtype=torch.float32)[:, None, None]
        self.rescale_factor = rescale_factor

    @classmethod
    def from_pretrained(cls, name: str, local: bool) -> DepthProProcessor:
        from transformers.image_processing_utils import ImageProcessingMixin

        cfg, _ = ImageProcessingMixin.get_image_processor_dict(name, local_files_only=local)
        return cls(cfg.get("size", {"height": 1536, "width": 1536}), cfg.get("image_mean", [0.5] * 3),
                   cfg.get("image_std", [0.5] * 3), cfg.get("rescale_factor", 1 / 255))

    def __call__(self, images, return_tensors: str = "pt"):
        from transformers import BatchFeature

        x = torch.from_numpy(np.stack(images)).permute(0, 3, 1, 2).float() * self.rescale_factor
        x = (x - self.mean) / self.std
        x = torch.nn.functional.interpolate(x, size=self.size, mode="bilinear", align_corners=False)
        return BatchFeature({"pixel_values": x})

    def post_process_depth_estimation(self, outputs, target_sizes):
        out = []
        for inv, fov, (h, w) in zip(outputs.predicted_depth, outputs.field_of_view, target_sizes, strict=True):
            f = 0.5 * w / torch.tan(0.5 * torch.deg2rad(fov))
            inv = torch.nn.functional.interpolate((inv * w / f)[None, None], size=(h, w), mode="bilinear",
                                                  align_corners=False)[0, 0]
            out.append({"predicted_depth": 1.0 / inv.clamp(1e-4, 1e4), "focal_length": f})
        return out


def _post_process_plain(outputs, H: int, W: int, zoe_padding: bool) -> list[dict]:
    """Depth at the frames' size (bicubic, no antialiasing: what ``transformers`` does with torchvision).
    ZoeDepth's processor pads each side by ``int(sqrt(size / 2) * 3)`` px (reflect); that border is cut off."""
    pred = outputs.predicted_depth.unsqueeze(1)
    out = []
    for d in pred:
        if zoe_padding:
            ph, pw = int(np.sqrt(H / 2) * 3), int(np.sqrt(W / 2) * 3)
            d = torch.nn.functional.interpolate(d[None], size=(H + 2 * ph, W + 2 * pw), mode="bicubic",
                                                align_corners=False)[0]
            d = d[:, ph:ph + H, pw:pw + W]
        d = torch.nn.functional.interpolate(d[None], size=(H, W), mode="bicubic", align_corners=False)[0]
        out.append({"predicted_depth": d[0]})
    return out


class UniDepthModel:
    """UniDepth (V1/V2) when the ``unidepth`` package is installed: metric depth and intrinsics."""

    def __init__(self, name: str, device: str = "cpu"):
        try:
            from unidepth.models import UniDepthV2
        except ImportError as e:
            raise InputError(f"{name}: UniDepth is not installed (see github.com/lpiccinelli-eth/UniDepth)") from e
        try:
            self.model = UniDepthV2.from_pretrained(name).to(device).eval()
        except OSError as e:
            raise InputError(f"{name}: cannot load UniDepth ({str(e).splitlines()[0]})") from e
        self.name, self.device = name, device
        self.kind = "metric"

    @torch.no_grad()
    def predict(self, frames: np.ndarray, verbose: bool = True) -> DepthPrediction:
        T, H, W = frames.shape[:3]
        out = np.zeros((T, H, W), np.float32)
        focals = []
        for t in range(T):
            rgb = torch.from_numpy(np.ascontiguousarray(frames[t])).permute(2, 0, 1).to(self.device)
            pred = self.model.infer(rgb)
            out[t] = pred["depth"].reshape(H, W).float().cpu().numpy()
            if "intrinsics" in pred:
                Kp = pred["intrinsics"].reshape(3, 3).float().cpu().numpy()
                focals.append(focal_length(Kp))
            if verbose and (t + 1) % 8 == 0:
                print(f"[depth] {self.name}: {t + 1}/{T} frames", file=sys.stderr, flush=True)
        return DepthPrediction(out, "metric", float(np.median(focals)) if focals else None, self.name)


def load_depth_model(spec: str, device: str = "cpu"):
    """A depth model from a short name (see ``DEPTH_MODELS``), ``hf:ID``, ``unidepth:ID`` or a local folder."""
    name = DEPTH_MODELS.get(spec, spec)
    if name.startswith("unidepth:"):
        return UniDepthModel(name.split(":", 1)[1], device)
    return HFDepthModel(name.removeprefix("hf:"), device)
