"""``trackingworld synth``: render a scene and write the user-facing inputs and the ground truth.

Layout of ``OUT``::

    input/frames/00000.png ...   RGB frames
    input/depth.npy              float32 [T,H,W] metres: corrupted depth prior
    input/masks/00000.png ...    coarse dynamic masks (255 = dynamic), background movers missing
    input/intrinsics.txt         3x3 K
    gt.npz                       exact ground truth (see GT_KEYS)
"""

from __future__ import annotations

import os
import shutil
import sys
from dataclasses import asdict
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from trackingworld.io.atomic import write_json, write_npz, write_text
from trackingworld.progress import Progress
from trackingworld.synth.corrupt import coarse_masks, corrupt_depth
from trackingworld.synth.render import follow_points, render
from trackingworld.synth.scene import Scene, make_scene

GT_KEYS = {
    "poses_c2w": "[T,4,4] camera-to-world",
    "K": "[3,3] intrinsics",
    "depth": "[T,H,W] exact depth, metres",
    "dynamic": "[T,H,W] bool, pixel on a moving object",
    "bg_mover": "[T,H,W] bool, pixel on a moving object the coarse masks miss",
    "instance": "[T,H,W] int16 primitive index",
    "tracks_xyz": "[N,T,3] world metres",
    "tracks_uv": "[N,T,2] pixels",
    "tracks_vis": "[N,T] bool",
    "query_frame": "[N] int32",
    "query_uv": "[N,2] pixels",
    "tracks_dynamic": "[N] bool",
    "tracks_bg_mover": "[N] bool",
    "flow_frames": "[2] (source, target) frames of the long-range flow ground truth",
    "flow": "[H,W,2] pixel displacement from the source frame to the target frame",
    "flow_occluded": "[H,W] bool, source pixel not visible in the target frame",
}


def _write_png(path: Path, img: np.ndarray) -> None:
    tmp = path.with_name(f".{path.name}.tmp.png")
    iio.imwrite(tmp, img)
    os.replace(tmp, path)


def sample_queries(scene: Scene, inst: np.ndarray, moving_ids: np.ndarray, rng) -> tuple[np.ndarray, np.ndarray]:
    """Query (frame, x, y) on evenly spaced frames: half uniform, half on moving objects."""
    cfg = scene.config
    T = scene.T
    qframes = np.unique(np.linspace(0, T - 1, cfg.n_query_frames + 1)[:-1].round().astype(int))
    qs, qt = [], []
    for t in qframes:
        ys, xs = np.mgrid[0:cfg.height, 0:cfg.width]
        xs, ys = xs.ravel(), ys.ravel()
        on_mover = np.isin(inst[t].ravel(), moving_ids)
        n = cfg.queries_per_frame
        pick = rng.choice(len(xs), size=n // 2, replace=False)
        mv = np.flatnonzero(on_mover)
        if len(mv):
            pick = np.concatenate([pick, rng.choice(mv, size=min(n - n // 2, len(mv)), replace=False)])
        pick = np.unique(pick)
        qs.append(np.stack([xs[pick], ys[pick]], 1))
        qt.append(np.full(len(pick), t))
    return np.concatenate(qt).astype(np.int32), np.concatenate(qs).astype(np.float64)


def render_and_write(out: str | os.PathLike, preset: str = "default", seed: int = 0,
                     frames: int | None = None, size: tuple[int, int] | None = None,
                     verbose: bool = True, fov_deg: float | None = None, **scene: float) -> Path:
    """Render a scene and write inputs + ground truth to ``out``. Returns ``out``. Further keywords override
    fields of the preset's :class:`SceneConfig` (e.g. ``cam_speed=0.15``)."""
    overrides = dict(scene)
    if fov_deg:
        overrides["fov_deg"] = float(fov_deg)
    if frames:
        overrides["frames"] = int(frames)
    if size:
        overrides["width"], overrides["height"] = int(size[0]), int(size[1])
    scene = make_scene(preset, seed=seed, **overrides)
    cfg = scene.config
    out = Path(out)
    rng = np.random.default_rng(seed + 7919)

    bar = Progress("synth: rendering frame", scene.T, verbose)
    r = render(scene, lambda i, n: bar.update(i))
    moving_ids = np.array([i for i, p in enumerate(scene.prims) if p.moving])
    masked_ids = np.array([i for i, p in enumerate(scene.prims) if p.moving and p.masked])
    bg_ids = np.array([i for i, p in enumerate(scene.prims) if p.moving and not p.masked])
    dynamic = np.isin(r.instance, moving_ids)
    bg_mover = np.isin(r.instance, bg_ids)

    # ground-truth tracks of query points
    qt, quv = sample_queries(scene, r.instance, moving_ids, rng)
    qx, qy = quv[:, 0].astype(int), quv[:, 1].astype(int)
    prim = r.instance[qt, qy, qx].astype(np.int64)
    local = r.local[qt, qy, qx].astype(np.float64)
    if verbose:
        print(f"[synth] ground-truth tracks for {len(qt)} query points", file=sys.stderr)
    xyz, uv, vis = follow_points(scene, prim, local)
    # long-range flow ground truth (CVO protocol: last frame of a 7-frame clip to its first)
    src, dst = min(6, scene.T - 1), 0
    H, W = cfg.height, cfg.width
    ys, xs = np.mgrid[0:H, 0:W]
    fprim = r.instance[src].ravel().astype(np.int64)
    flocal = r.local[src].reshape(-1, 3).astype(np.float64)
    _, fuv, fvis = follow_points(scene, fprim, flocal, frames=[dst])
    flow = (fuv[:, 0] - np.stack([xs.ravel(), ys.ravel()], 1)).reshape(H, W, 2)

    # priors as a user would have them
    prior = corrupt_depth(r.depth, cfg, rng)
    masks = coarse_masks(np.isin(r.instance, masked_ids), cfg, rng)

    if out.exists() and (out / "gt.npz").exists():
        shutil.rmtree(out / "input", ignore_errors=True)
    (out / "input" / "frames").mkdir(parents=True, exist_ok=True)
    (out / "input" / "masks").mkdir(parents=True, exist_ok=True)
    for t in range(scene.T):
        _write_png(out / "input" / "frames" / f"{t:05d}.png", r.frames[t])
        _write_png(out / "input" / "masks" / f"{t:05d}.png", (masks[t] * 255).astype(np.uint8))
    tmp = out / "input" / ".depth.tmp.npy"
    np.save(tmp, prior)
    os.replace(tmp, out / "input" / "depth.npy")
    write_text(out / "input" / "intrinsics.txt", "\n".join(" ".join(f"{v:.6f}" for v in row) for row in scene.K) + "\n")
    write_npz(
        out / "gt.npz",
        poses_c2w=scene.poses_c2w.astype(np.float32), K=scene.K.astype(np.float32),
        depth=r.depth.astype(np.float32), dynamic=dynamic, bg_mover=bg_mover,
        instance=r.instance, tracks_xyz=xyz.astype(np.float32), tracks_uv=uv.astype(np.float32),
        tracks_vis=vis, query_frame=qt, query_uv=quv.astype(np.float32),
        tracks_dynamic=np.isin(prim, moving_ids), tracks_bg_mover=np.isin(prim, bg_ids),
        flow_frames=np.array([src, dst], np.int32), flow=flow.astype(np.float32),
        flow_occluded=~fvis[:, 0].reshape(H, W),
    )
    write_json(out / "scene.json", {
        "preset": preset, "seed": seed, "config": asdict(cfg),
        "objects": [{"name": p.name, "moving": p.moving, "masked": p.masked} for p in scene.prims],
        "gt_keys": GT_KEYS,
    })
    return out
