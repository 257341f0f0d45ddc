"""CoTracker3 as the sparse tracker (``--tracker cotracker3``): the learned option beside the weight-free flow
tracker, used by the same dense machinery (grid + convex upsampler, tracking every frame).

Loading, by ``--cotracker`` spec:

- ``cotracker3`` (default): ``torch.hub.load("facebookresearch/co-tracker", "cotracker3_offline")`` (downloads
  code and weights once into the torch hub cache);
- ``hub:REPO_OR_DIR[:ENTRY]``: another hub repository or a local clone (``source="local"`` for a folder), entry
  ``cotracker3_offline`` unless given;
- a ``.pth`` checkpoint: ``cotracker.predictor.CoTrackerPredictor(checkpoint=PATH)`` from the installed
  ``cotracker`` package.

The model is called with CoTracker's predictor API: ``model(video [1,T,3,H,W] float 0..255, queries=[1,N,3]
(t, x, y), backward_tracking=True)`` -> ``tracks [1,T,N,2]`` pixels, ``visibility [1,T,N]`` bool. With
``backward_tracking`` a query in frame t is tracked into the frames before t as well, so tracks run in both
directions of time like the flow tracker's. Queries go in chunks to bound memory.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from trackingworld.errors import InputError
from trackingworld.tracking2d.base import TrackResult, hold_invisible

HUB_REPO = "facebookresearch/co-tracker"
HUB_ENTRY = "cotracker3_offline"


@dataclass
class CoTrackerConfig:
    spec: str = "cotracker3"
    device: str = "cpu"
    max_queries: int = 4096  # queries per model call
    verbose: bool = True


def load_cotracker(spec: str, device: str = "cpu"):
    """The CoTracker predictor named by ``spec`` (see the module docstring), in eval mode on ``device``."""
    import torch

    try:
        if spec == "cotracker3":
            model = torch.hub.load(HUB_REPO, HUB_ENTRY, trust_repo=True)
        elif spec.startswith("hub:"):
            repo, entry = spec[4:], HUB_ENTRY
            if not Path(repo).exists() and repo.count(":") >= 1:  # owner/name[:ref]:ENTRY or DIR:ENTRY
                repo, entry = repo.rsplit(":", 1)
            if Path(repo).exists():
                model = torch.hub.load(repo, entry, source="local")
            else:
                model = torch.hub.load(repo, entry, trust_repo=True)
        elif spec.endswith((".pth", ".pt")):
            if not Path(spec).exists():
                raise InputError(f"{spec}: no such checkpoint")
            try:
                from cotracker.predictor import CoTrackerPredictor
            except ImportError as e:
                raise InputError(f"{spec}: loading a CoTracker checkpoint needs the cotracker package "
                                 "(pip install git+https://github.com/facebookresearch/co-tracker)") from e
            model = CoTrackerPredictor(checkpoint=spec)
        else:
            raise InputError(f"--cotracker {spec}: expected cotracker3, hub:REPO_OR_DIR[:ENTRY] or a .pth file")
    except InputError:
        raise
    except Exception as e:  # hub download / import failures come in many types
        raise InputError(f"--cotracker {spec}: cannot load ({type(e).__name__}: {str(e).splitlines()[0]})") from e
    return model.to(device).eval()


class CoTrackerTracker:
    """The :class:`~trackingworld.tracking2d.base.Tracker` interface over a CoTracker predictor."""

    def __init__(self, model, cfg: CoTrackerConfig | None = None):
        self.model = model
        self.cfg = cfg or CoTrackerConfig()
        self._video = None
        self._video_of = None

    @classmethod
    def from_spec(cls, cfg: CoTrackerConfig) -> CoTrackerTracker:
        """The tracker over the predictor ``cfg.spec`` names, loaded once per process (``loaded_models``)."""
        from trackingworld.loaded_models import loaded

        return cls(loaded("tracker", cfg.spec, cfg.device, load_cotracker), cfg)

    def _video_tensor(self, frames: np.ndarray):
        import torch

        if self._video_of is not frames:  # converted once per video, not once per query frame
            v = torch.from_numpy(np.ascontiguousarray(frames)).permute(0, 3, 1, 2)[None].float()
            self._video, self._video_of = v.to(self.cfg.device), frames
        return self._video

    def track(self, frames: np.ndarray, queries: np.ndarray) -> TrackResult:
        """frames [T,H,W,3] uint8, queries [N,3] (t, x, y) -> tracks [N,T,2] in both directions of time."""
        import torch

        T = frames.shape[0]
        N = len(queries)
        video = self._video_tensor(frames)
        tracks = np.zeros((N, T, 2), np.float32)
        vis = np.zeros((N, T), bool)
        for a in range(0, N, self.cfg.max_queries):
            q = torch.from_numpy(np.asarray(queries[a:a + self.cfg.max_queries], np.float32))[None]
            with torch.no_grad():
                tr, vv = self.model(video, queries=q.to(self.cfg.device), backward_tracking=True)
            tr, vv = tr[0].float().cpu().numpy(), vv[0].cpu().numpy()
            if tr.shape != (T, len(q[0]), 2):
                raise RuntimeError(f"CoTracker returned tracks of shape {tr.shape}, expected {(T, len(q[0]), 2)}")
            tracks[a:a + len(q[0])] = tr.transpose(1, 0, 2)
            vis[a:a + len(q[0])] = (vv > 0.5 if vv.dtype != bool else vv).reshape(T, -1).T
        qt = np.round(queries[:, 0]).astype(int)
        tracks[np.arange(N), qt] = queries[:, 1:3]
        vis[np.arange(N), qt] = True
        # CoTracker estimates occluded points too: keep its estimate, hold only where it is not finite
        bad = ~np.isfinite(tracks).all(-1)
        if bad.any():
            tracks = np.where(bad[..., None], hold_invisible(np.nan_to_num(tracks), vis & ~bad), tracks)
        if self.cfg.verbose:
            print(f"[cotracker] {N} queries over {T} frames", file=sys.stderr, flush=True)
        return TrackResult(tracks, vis, vis.astype(np.float32), np.asarray(queries, np.float32))
