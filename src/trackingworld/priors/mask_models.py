"""Dynamic masks from pretrained models: a text-prompted detector (Grounding DINO) boxes the objects named in
the prompt, a promptable segmenter (SAM) turns each box into a mask; both through ``transformers``.

The prompt names what may move ("person. dog. car."): like the paper's coarse masks, these mark objects that
*can* move; stage 2 of the optimiser still keeps such an object static when it is."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

from trackingworld.errors import InputError

MASK_MODELS = {"grounded-sam": ("IDEA-Research/grounding-dino-tiny", "facebook/sam-vit-base")}
DEFAULT_PROMPT = "person. animal. dog. cat. horse. sheep. cow. bird. car. bicycle. vehicle."


def is_mask_model_spec(spec: str) -> bool:
    """``grounded-sam``, or ``DETECTOR+SEGMENTER`` (hub ids or local folders)."""
    return spec in MASK_MODELS or ("+" in spec and not Path(spec).exists())


def _load(cls_name: str, name: str):
    import transformers

    local = Path(name).is_dir()
    try:
        return getattr(transformers, cls_name).from_pretrained(name, local_files_only=local)
    except (OSError, ValueError) as e:
        raise InputError(f"{name}: cannot load ({str(e).splitlines()[0]}); models download from the Hugging Face "
                         "hub on first use, or give a local folder") from e


class GroundedSAM:
    def __init__(self, detector: str, segmenter: str, device: str = "cpu", box_threshold: float = 0.3,
                 text_threshold: float = 0.25):
        try:
            import transformers  # noqa: F401
        except ImportError as e:
            raise InputError("mask models need transformers (pip install 'trackingworld[models]')") from e
        self.det_proc = _load("AutoProcessor", detector)
        self.det = _load("AutoModelForZeroShotObjectDetection", detector).to(device).eval()
        self.seg_proc = _load("SamProcessor", segmenter)
        self.seg = _load("SamModel", segmenter).to(device).eval()
        self.device, self.box_threshold, self.text_threshold = device, box_threshold, text_threshold
        self.name = f"{detector}+{segmenter}"

    @torch.no_grad()
    def boxes(self, image: np.ndarray, prompt: str) -> np.ndarray:
        """Boxes [B,4] (x0, y0, x1, y1 px) of the objects the prompt names."""
        H, W = image.shape[:2]
        inputs = self.det_proc(images=image, text=prompt, return_tensors="pt").to(self.device)
        out = self.det(**inputs)
        res = self.det_proc.post_process_grounded_object_detection(
            out, inputs["input_ids"], threshold=self.box_threshold, text_threshold=self.text_threshold,
            target_sizes=[(H, W)])[0]
        return res["boxes"].float().cpu().numpy().reshape(-1, 4)

    @torch.no_grad()
    def segment(self, image: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """Union of the box-prompted masks [H,W] bool."""
        H, W = image.shape[:2]
        if len(boxes) == 0:
            return np.zeros((H, W), bool)
        inputs = self.seg_proc(images=image, input_boxes=[boxes.tolist()], return_tensors="pt").to(self.device)
        out = self.seg(**inputs, multimask_output=False)
        masks = self.seg_proc.post_process_masks(out.pred_masks.cpu(), inputs["original_sizes"].cpu(),
                                                 inputs["reshaped_input_sizes"].cpu())[0]
        return masks.reshape(-1, H, W).any(0).numpy()

    def predict(self, frames: np.ndarray, prompt: str = DEFAULT_PROMPT, verbose: bool = True) -> np.ndarray:
        """frames [T,H,W,3] uint8 -> masks [T,H,W] bool."""
        T, H, W = frames.shape[:3]
        out = np.zeros((T, H, W), bool)
        for t in range(T):
            out[t] = self.segment(frames[t], self.boxes(frames[t], prompt))
            if verbose and ((t + 1) % 8 == 0 or t == T - 1):
                print(f"[masks] {self.name}: {t + 1}/{T} frames, {out[t].mean() * 100:.1f}% dynamic",
                      file=sys.stderr, flush=True)
        return out


def load_mask_model(spec: str, device: str = "cpu") -> GroundedSAM:
    det, seg = MASK_MODELS.get(spec) or spec.split("+", 1)
    return GroundedSAM(det, seg, device)
