"""What to draw of a result, as pure functions on arrays: which tracks, where, in which colour.

Shared by the interactive viewer, the renderer and the rerun export. Conventions as everywhere in the
package: world metres, camera-to-world 4x4 poses, OpenCV camera axes (x right, y down, z forward), pixels
x right / y down. Display subsamples, it never edits the result: every function returns indices into it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackingworld.geometry import invert_pose, nearest_pixel, transform
from trackingworld.optim.label_steps import LABEL_STEPS

STATIC_COLOR = np.array([120, 150, 190], np.uint8)  # label colours: static blue-grey
DYNAMIC_COLOR = np.array([255, 110, 20], np.uint8)  # dynamic orange
COLOR_MODES = ("video", "video + dynamic tint", "label", "label step", "object", "depth")
# "object": one colour per rigid object (result.npz's object_id), cycling through these; the tracks of no object keep
# the label colours (matplotlib's tab10 without its blue, grey and orange, which the label colours use)
OBJECT_COLORS = np.array([(44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75), (227, 119, 194),
                          (188, 189, 34), (23, 190, 207)], np.uint8)
# "label step": one colour per step of optim.label_steps.LABEL_STEPS that set the label (result.npz's label_step),
# with its name for a legend; the masks' own label keeps the label colours' blue-grey / orange
STEP_COLORS = {
    "masks": None,
    "stage2": ((214, 39, 40), "red"),
    "classify": ((148, 103, 189), "purple"),
    "rebuild_static": ((140, 86, 75), "brown"),
    "depth_movers": ((227, 119, 194), "pink"),
    "vote": ((188, 189, 34), "olive"),
    "photo_static": ((23, 190, 207), "cyan"),
    "occluded_static": ((44, 160, 44), "green"),
    "photo_moving": ((255, 215, 0), "yellow"),
}
assert tuple(STEP_COLORS) == LABEL_STEPS


@dataclass
class DisplayConfig:
    """How much of a dense result is drawn. Defaults keep a browser smooth with ~1M-track results."""

    max_points: int = 150_000  # points of the current frame
    max_static_points: int = 300_000  # points of the accumulated static map
    trail_tracks: int = 400  # dynamic tracks drawn with trails
    trail_length: int = 12  # frames of a trail
    seed: int = 0


def display_order(n: int, seed: int = 0) -> np.ndarray:
    """A fixed random permutation of ``n`` track indices. Taking its first k members that pass a filter gives
    nested, stable subsets: more density adds points and never swaps the ones already drawn."""
    return np.random.default_rng(seed).permutation(n)


def first_k(order: np.ndarray, keep: np.ndarray, k: int) -> np.ndarray:
    """The first ``k`` indices of ``order`` where ``keep`` [N] bool holds, in ``order``'s order."""
    idx = order[keep[order]]
    return idx[:k] if k is not None and k >= 0 else idx


def frame_indices(visible: np.ndarray, t: int, order: np.ndarray, k: int) -> np.ndarray:
    """Indices of up to ``k`` tracks visible in frame ``t`` (``visible`` [N,T] bool)."""
    return first_k(order, visible[:, t], k)


def static_map(tracks_3d: np.ndarray, query_frame: np.ndarray, is_dynamic: np.ndarray, order: np.ndarray,
               k: int) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``k`` static tracks and their world position at their query frame: (indices [M], xyz [M,3])."""
    idx = first_k(order, ~is_dynamic, k)
    return idx, tracks_3d[idx, query_frame[idx]]


def sample_colors(frame: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """RGB [M,3] uint8 of ``frame`` [H,W,3] at the nearest pixel of ``uv`` [M,2] (clamped to the image)."""
    x, y = nearest_pixel(uv, frame.shape[1], frame.shape[0])
    return frame[y, x]


def query_colors(frames: np.ndarray | None, tracks_2d: np.ndarray, query_frame: np.ndarray, colors: np.ndarray,
                 idx: np.ndarray) -> np.ndarray:
    """RGB [M,3] uint8 of tracks ``idx`` at their query frame: from ``frames`` [T,H,W,3] when given, else the
    result's own ``colors`` [N,3]."""
    if frames is None:
        return colors[idx]
    qf = query_frame[idx]
    x, y = nearest_pixel(tracks_2d[idx, qf], frames.shape[2], frames.shape[1])
    return frames[qf, y, x]


def depth_colors(z: np.ndarray, lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """Turbo colours [M,3] uint8 of depths ``z`` [M] (near red, far blue), on the 2-98 percentile range."""
    import cv2

    if z.size == 0:
        return np.zeros((0, 3), np.uint8)
    lo = np.percentile(z, 2) if lo is None else lo
    hi = np.percentile(z, 98) if hi is None else hi
    v = np.clip((hi - z) / max(hi - lo, 1e-9), 0, 1)
    lut = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], cv2.COLORMAP_TURBO)[:, 0, ::-1]
    return lut[np.rint(v * 255).astype(np.int64)]


def label_colors(dyn: np.ndarray) -> np.ndarray:
    """Colours [M,3] uint8 of tracks by their label ``dyn`` [M] bool: blue-grey static, orange dynamic."""
    return np.where(dyn[:, None], DYNAMIC_COLOR, STATIC_COLOR).astype(np.uint8)


def step_legend() -> str:
    """The "label step" colours as one line of markdown (step: colour name)."""
    return " &nbsp; ".join(f"{name}: {'label colours' if c is None else c[1]}" for name, c in STEP_COLORS.items())


def step_colors(label_step: np.ndarray, dyn: np.ndarray) -> np.ndarray:
    """Colours [M,3] uint8 of tracks by the step that set their label (``label_step`` [M] codes of
    :data:`~trackingworld.optim.label_steps.LABEL_STEPS`): :data:`STEP_COLORS`, the label colours where no step
    changed the masks' label (``dyn`` [M] bool their labels)."""
    out = label_colors(dyn)
    for code, c in enumerate(STEP_COLORS.values()):
        if c is not None:
            out[label_step == code] = c[0]
    return out


def object_colors(object_id: np.ndarray, dyn: np.ndarray) -> np.ndarray:
    """Colours [M,3] uint8 of tracks by their rigid object (``object_id`` [M], -1: none): :data:`OBJECT_COLORS`
    in turn, the label colours where a track is in no object (``dyn`` [M] bool their labels)."""
    out = label_colors(dyn)
    some = object_id >= 0
    out[some] = OBJECT_COLORS[object_id[some] % len(OBJECT_COLORS)]
    return out


def point_colors(mode: str, idx: np.ndarray, t: int, *, tracks_2d: np.ndarray, is_dynamic: np.ndarray,
                 colors: np.ndarray, frame: np.ndarray | None = None, depth: np.ndarray | None = None,
                 label_step: np.ndarray | None = None, object_id: np.ndarray | None = None) -> np.ndarray:
    """Colours [M,3] uint8 of tracks ``idx`` in frame ``t`` for a colour ``mode`` of :data:`COLOR_MODES`.

    ``video`` samples the current frame (the query-frame colour ``colors`` [N,3] without frames); ``label``
    is blue-grey static / orange dynamic; ``label step`` colours by the step that set the label
    (:func:`step_colors` of ``label_step`` [N]; the label colours for a result without it); ``object`` by the
    rigid object (:func:`object_colors` of ``object_id`` [N]; likewise); ``depth`` needs the tracks' camera depths
    ``depth`` [M]."""
    if mode not in COLOR_MODES:
        raise ValueError(f"unknown colour mode {mode!r} (one of {', '.join(COLOR_MODES)})")
    dyn = is_dynamic[idx]
    if mode == "label step" and label_step is not None:
        return step_colors(label_step[idx], dyn)
    if mode == "object" and object_id is not None:
        return object_colors(object_id[idx], dyn)
    if mode in ("label", "label step", "object"):
        return label_colors(dyn)
    if mode == "depth":
        return depth_colors(depth)
    rgb = sample_colors(frame, tracks_2d[idx, t]) if frame is not None else colors[idx]
    if mode == "video + dynamic tint":
        rgb = rgb.astype(np.float32)
        rgb[dyn] = 0.6 * rgb[dyn] + 0.4 * DYNAMIC_COLOR
        rgb = rgb.astype(np.uint8)
    return rgb


def frame_points(res, t: int, order: np.ndarray, k: int, mode: str, frame: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What is drawn of frame ``t`` of a :class:`~trackingworld.io.result.Result`: up to ``k`` visible tracks
    (nested prefix of ``order``), (indices [M], world points [M,3], colours [M,3] in ``mode``; ``frame``
    [H,W,3] is that frame of the video, when there is one)."""
    idx = frame_indices(res.visible, t, order, k)
    pts = res.tracks_3d[idx, t]
    depth = camera_depths(pts, res.poses_c2w[t]) if mode == "depth" else None
    col = point_colors(mode, idx, t, tracks_2d=res.tracks_2d, is_dynamic=res.is_dynamic, colors=res.colors,
                       frame=frame, depth=depth, label_step=res.label_step, object_id=res.object_id)
    return idx, pts, col


def trail_indices(is_dynamic: np.ndarray, visible: np.ndarray, order: np.ndarray, k: int) -> np.ndarray:
    """Up to ``k`` dynamic tracks for trails, preferring tracks visible in many frames."""
    dyn = order[is_dynamic[order]]
    if dyn.size <= k:
        return dyn
    seen = visible[dyn].sum(1)
    keep = np.argsort(-seen, kind="stable")[: 4 * k]  # the best-observed quarter, then a spread sample
    return dyn[np.sort(keep)[:k]]


def trail_segments(tracks_3d: np.ndarray, idx: np.ndarray, t: int, length: int,
                   visible: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Line segments of the last ``length`` frames of tracks ``idx`` up to frame ``t``.

    With ``visible`` [N,T] only segments observed at both ends are kept (positions through occlusion are
    estimates, and a trail should show what was seen). Returns (segments [S,2,3] world metres, fade [S] in
    (0,1], 1 at the newest segment)."""
    t0 = max(0, t - length)
    if t - t0 < 1 or idx.size == 0:
        return np.zeros((0, 2, 3), np.float32), np.zeros(0, np.float32)
    p = tracks_3d[idx, t0:t + 1]  # [M,L+1,3]
    seg = np.stack([p[:, :-1], p[:, 1:]], axis=2).reshape(-1, 2, 3)
    L = t - t0
    fade = np.tile(np.arange(1, L + 1, dtype=np.float32) / L, idx.size)
    if visible is not None:
        v = visible[idx, t0:t + 1]
        keep = (v[:, :-1] & v[:, 1:]).reshape(-1)
        seg, fade = seg[keep], fade[keep]
    return seg.astype(np.float32), fade


def fade_to(colors: np.ndarray, fade: np.ndarray, background=(255, 255, 255)) -> np.ndarray:
    """Blend colours [M,3] toward ``background`` as ``fade`` [M] goes to 0 (a trail fading out)."""
    bg = np.asarray(background, np.float32)
    out = bg + (colors.astype(np.float32) - bg) * fade[:, None]
    return np.clip(out, 0, 255).astype(np.uint8)


def trail_colors(fade: np.ndarray) -> np.ndarray:
    """Colours [S,3] uint8 of trail segments: the dynamic colour fading to white as ``fade`` [S] goes to 0."""
    return fade_to(np.broadcast_to(DYNAMIC_COLOR, (len(fade), 3)), fade)


def camera_depths(tracks_3d_t: np.ndarray, pose_c2w: np.ndarray) -> np.ndarray:
    """Camera z [M] of world points [M,3] seen from a camera-to-world pose."""
    return transform(invert_pose(pose_c2w.astype(np.float64)), tracks_3d_t.astype(np.float64))[:, 2]


def median_depth(depth: np.ndarray) -> float:
    """Median of the valid depths [T,H,W] (metres), on every 4th pixel: a scale for sizing things on screen."""
    d = depth[:, ::4, ::4]
    d = d[np.isfinite(d) & (d > 0)]
    return float(np.median(d)) if d.size else 1.0


def scene_extent(poses_c2w: np.ndarray, med_depth: float) -> float:
    """A length for sizing things on screen: the median scene depth (metres), never below the camera path's
    extent."""
    c = poses_c2w[:, :3, 3]
    return max(med_depth, float(np.linalg.norm(c.max(0) - c.min(0))), 1e-6)


def base_point_size(fx: float, med_depth: float, drawn: int, total: int) -> float:
    """World point size (metres) that makes ``drawn`` of ``total`` points about cover the surface they sample:
    one pixel's footprint at the median depth, grown by sqrt of the subsampling factor."""
    return 1.5 * med_depth / float(fx) * float(np.sqrt(max(total, 1) / max(drawn, 1)))


def vertical_fov(K: np.ndarray, height: int) -> float:
    """Vertical field of view in radians of a pinhole ``K`` for an image ``height`` px tall."""
    return float(2.0 * np.arctan2(height / 2.0, K[1, 1]))
