"""``trackingworld render DIR``: files to share without running anything, written into ``DIR/render/``.

- ``tracks_2d.mp4``: the input video with a subset of the 2D tracks and short tails, coloured by camera depth
  (near red, far blue) or by label (static blue-grey, dynamic orange);
- ``scene_3d.mp4``: the world-frame scene (static map, the current frame's dynamic points, dynamic trails,
  the camera and its path so far) from an orbiting, a following or the estimated camera's viewpoint;
- ``camera_path.png``: the camera path, against the ground truth when ``--gt SCENE`` is given.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from trackingworld.errors import InputError
from trackingworld.geometry import default_intrinsics, look_at
from trackingworld.io.atomic import atomic_path, check_writable
from trackingworld.io.frames import frames_for_result
from trackingworld.io.result import Result, load_result
from trackingworld.progress import Progress
from trackingworld.viz import display as D
from trackingworld.viz.plots import plot_camera_path
from trackingworld.viz.splat import draw_polyline, follow_poses, frustum_lines, orbit_poses, splat

RENDER_DIR = "render"
COLOR_BY = ("depth", "label", "step", "object")  # the colours of tracks_2d.mp4 (RenderConfig.color_by)
VIEWS = ("orbit", "follow", "input", "fixed")


@dataclass
class RenderConfig:
    # tracks_2d.mp4: depth | label | step (the step that set the label, display.STEP_COLORS) | object (the rigid
    # object that placed the track, display.OBJECT_COLORS)
    color_by: str = "depth"
    max_tracks: int = 600  # tracks drawn per frame in tracks_2d.mp4 (about)
    tail: int = 8  # frames of a 2D tail
    view: str = "orbit"  # scene_3d.mp4 viewpoint: orbit | follow | input | fixed (at eye, looking at target)
    eye: tuple[float, float, float] | None = None  # fixed: world position of the viewpoint (metres)
    target: tuple[float, float, float] | None = None  # fixed: point looked at (default: the static map's median)
    swing_deg: float = 30.0  # orbit: swing about the world up
    elevation_deg: float = 20.0
    max_points: int = 200_000  # static map points in scene_3d.mp4
    long_side: int = 960  # scene_3d.mp4 width/height cap
    fps: float = 10.0
    seed: int = 0

    def validate(self) -> None:
        """One-line errors for settings that cannot render."""
        if self.color_by not in COLOR_BY:
            raise InputError(f"--color-by must be one of {', '.join(COLOR_BY)}, got {self.color_by!r}")
        if self.view not in VIEWS:
            raise InputError(f"--view must be one of {', '.join(VIEWS)}, got {self.view!r}")
        if self.view == "fixed" and self.eye is None:
            raise InputError("--view fixed needs --eye X,Y,Z (world metres; the first camera is at "
                             "poses_tum.txt's first line)")


def write_video(path: str | os.PathLike, frames, fps: float) -> None:
    """Write RGB frames (an iterable of [H,W,3] uint8, even sizes) as H.264 mp4, atomically."""
    import imageio.v3 as iio

    with atomic_path(path) as tmp, iio.imopen(tmp, "w", plugin="pyav") as f:
        f.init_video_stream("libx264", fps=fps)
        for frame in frames:  # streamed: a long video never sits in memory whole
            f.write_frame(np.ascontiguousarray(frame))


def _even(img: np.ndarray) -> np.ndarray:
    H, W = img.shape[:2]
    return img[: H - H % 2, : W - W % 2]


def _track_subset(visible: np.ndarray, order: np.ndarray, per_frame: int) -> np.ndarray:
    """A fixed subset of tracks (nested prefix of ``order``) with about ``per_frame`` visible in a median frame;
    fixed so that a drawn track keeps being drawn."""
    med = float(np.median(visible.sum(0))) if visible.size else 0.0
    k = int(np.ceil(per_frame * len(order) / max(med, 1.0)))
    return np.sort(order[:k])


def tracks_video_frames(res: Result, frames: np.ndarray, cfg: RenderConfig):
    """Yield the overlay frames [H,W,3] uint8 of ``tracks_2d.mp4``."""
    cfg.validate()
    order = D.display_order(res.num_tracks, cfg.seed)
    idx = _track_subset(res.visible, order, cfg.max_tracks)
    uv = res.tracks_2d[idx]
    vis = res.visible[idx]
    if cfg.color_by == "step":
        step = res.require("label_step", "--color-by step")
        col = D.step_colors(step[idx], res.is_dynamic[idx])[:, None].repeat(res.num_frames, 1)
    elif cfg.color_by == "object":
        object_id = res.require("object_id", "--color-by object")
        col = D.object_colors(object_id[idx], res.is_dynamic[idx])[:, None].repeat(res.num_frames, 1)
    elif cfg.color_by == "label":
        col = D.label_colors(res.is_dynamic[idx])[:, None].repeat(res.num_frames, 1)
    else:  # depth
        z = np.stack([D.camera_depths(res.tracks_3d[idx, t], res.poses_c2w[t]) for t in range(res.num_frames)], 1)
        zs = z[vis] if vis.any() else z.ravel()
        col = D.depth_colors(z.ravel(), np.percentile(zs, 2), np.percentile(zs, 98)).reshape(len(idx), -1, 3)
    for t in range(res.num_frames):
        img = np.ascontiguousarray(frames[t])
        img = (0.7 * img).astype(np.uint8)  # darken so that the tracks stand out
        on = np.flatnonzero(vis[:, t])
        t0 = max(0, t - cfg.tail)
        for n in on:
            c = tuple(int(v) for v in col[n, t])
            pts = [uv[n, s] for s in range(t0, t + 1) if vis[n, s]]
            for a, b in zip(pts[:-1], pts[1:], strict=False):
                cv2.line(img, (int(round(a[0])), int(round(a[1]))), (int(round(b[0])), int(round(b[1]))), c, 1,
                         cv2.LINE_AA)
            cv2.circle(img, (int(round(uv[n, t, 0])), int(round(uv[n, t, 1]))), 2, c, -1, cv2.LINE_AA)
        cv2.putText(img, f"frame {t}", (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
        yield _even(img)


def scene_video_frames(res: Result, frames: np.ndarray | None, cfg: RenderConfig):
    """Yield the frames [h,w,3] uint8 of ``scene_3d.mp4``."""
    cfg.validate()
    T = res.num_frames
    H, W = res.depth.shape[1:]
    s = min(1.0, cfg.long_side / max(W, H))
    w, h = int(round(W * s)) // 2 * 2, int(round(H * s)) // 2 * 2
    order = D.display_order(res.num_tracks, cfg.seed)
    sidx, sxyz = D.static_map(res.tracks_3d, res.query_frame, res.is_dynamic, order, cfg.max_points)
    scol = D.query_colors(frames, res.tracks_2d, res.query_frame, res.colors, sidx)
    dyn_idx = order[res.is_dynamic[order]]
    trail_idx = D.trail_indices(res.is_dynamic, res.visible, order, 300)
    extent = D.scene_extent(res.poses_c2w, D.median_depth(res.depth))
    if cfg.view == "input":
        views, K = res.poses_c2w.astype(np.float64), res.intrinsics * s
        K[2, 2] = 1.0
    else:
        K = default_intrinsics(w, h, 60.0)
        target = np.median(sxyz, 0) if len(sxyz) else res.poses_c2w[0, :3, 3] + res.poses_c2w[0, :3, 2]
        dist = 2.0 * float(np.linalg.norm(target - res.poses_c2w[0, :3, 3])) + 1e-6
        if cfg.view == "orbit":
            views = orbit_poses(res.poses_c2w, target, dist, T, cfg.swing_deg, cfg.elevation_deg)
        elif cfg.view == "follow":
            views = follow_poses(res.poses_c2w, 0.5 * extent, cfg.elevation_deg)
        else:
            look = np.asarray(cfg.target if cfg.target is not None else target, np.float64)
            up = -res.poses_c2w[0, :3, 1].astype(np.float64)
            views = np.repeat(look_at(np.asarray(cfg.eye, np.float64), look, up=up)[None], T, axis=0)
    radius = 1 if max(w, h) >= 480 else 0
    centres = res.poses_c2w[:, :3, 3]
    for t in range(T):
        img = splat(sxyz, scol, views[t], K, (w, h), radius=radius)
        di = dyn_idx[res.visible[dyn_idx, t]]
        if len(di):
            dcol = D.point_colors("video + dynamic tint", di, t, tracks_2d=res.tracks_2d, is_dynamic=res.is_dynamic,
                                  colors=res.colors, frame=None if frames is None else frames[t])
            img = splat(res.tracks_3d[di, t], dcol, views[t], K, (w, h), radius=radius, image=img)
        seg, fade = D.trail_segments(res.tracks_3d, trail_idx, t, cfg.tail, res.visible)
        tc = D.trail_colors(fade)
        for (a, b), c in zip(seg, tc, strict=True):
            draw_polyline(img, np.stack([a, b]), views[t], K, tuple(int(v) for v in c), 1)
        if cfg.view != "input":
            draw_polyline(img, centres[: t + 1], views[t], K, (40, 40, 40), 2)
            for a, b in frustum_lines(res.poses_c2w[t], res.intrinsics, (W, H), 0.2 * extent):
                draw_polyline(img, np.stack([a, b]), views[t], K, (230, 90, 10), 2)
        cv2.putText(img, f"frame {t}  ({cfg.view} view)", (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (30, 30, 30), 1,
                    cv2.LINE_AA)
        yield img


def render(result_dir: str | Path, cfg: RenderConfig | None = None, gt: str | Path | None = None,
           video: str | None = None, what: tuple[str, ...] = ("tracks", "scene", "path"),
           verbose: bool = True) -> dict[str, Path]:
    """Write the chosen renders into ``DIR/render/``; returns {name: path}."""
    from trackingworld.eval.evaluate import load_gt

    cfg = cfg or RenderConfig()
    cfg.validate()  # before anything is read or written
    result_dir = Path(result_dir)
    res = load_result(result_dir)
    out_dir = result_dir / RENDER_DIR
    check_writable(out_dir, "render folder")  # before the videos are made
    frames, why = frames_for_result(result_dir, res.depth.shape, video)
    out: dict[str, Path] = {}
    if "tracks" in what:
        if frames is None:
            print(f"[render] skipping tracks_2d.mp4: no input frames ({why}); pass --video", file=sys.stderr)
        else:
            out["tracks"] = out_dir / "tracks_2d.mp4"
            write_video(out["tracks"], _progress(tracks_video_frames(res, frames, cfg), res.num_frames,
                                                 "render: 2D tracks", verbose), cfg.fps)
    if "scene" in what:
        out["scene"] = out_dir / "scene_3d.mp4"
        write_video(out["scene"], _progress(scene_video_frames(res, frames, cfg), res.num_frames,
                                            "render: 3D scene", verbose), cfg.fps)
    if "path" in what:
        out["path"] = out_dir / "camera_path.png"
        gt = gt or _gt_from_metrics(result_dir)
        gt_poses = load_gt(gt, res.num_frames)["poses_c2w"] if gt else None
        info = plot_camera_path(res.poses_c2w, out["path"], gt_poses, title=result_dir.name or "camera path")
        if verbose and "ate" in info:
            print(f"[render] camera path against {gt}: ATE {info['ate']:.4f} m", file=sys.stderr)
    if verbose:
        for p in out.values():
            print(f"[render] wrote {p}", file=sys.stderr)
    return out


def _gt_from_metrics(result_dir: Path) -> str | None:
    """The scene an earlier ``trackingworld eval`` compared this result with, if it still exists."""
    import json

    try:
        scene = json.loads((result_dir / "metrics.json").read_text()).get("gt_scene")
    except (OSError, ValueError):
        return None
    return scene if scene and Path(scene).exists() else None


def _progress(it, total: int, label: str, verbose: bool):
    p = Progress(label, total, verbose)
    for i, x in enumerate(it):
        yield x
        p.update(i + 1)
