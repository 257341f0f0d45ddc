"""Dynamic-labelled tracks that are static points the 2D tracker followed onto a mover passing in front of them.

When a mover passes in front of a background point, the point is hidden; the 2D tracker often does not say so and
follows the mover's edge instead, and the track's offsets from its static point grow in those frames. Every static
test on the 2D track then calls it dynamic, though it is that static point wherever the point can be seen.

The test asks the static hypothesis where it predicts the track: its query pixel lifted at the video depth there
(a static point), projected into each other frame the track is visible in (every frame read once, so the cost is
the candidates' observations). In a frame where the consistent video depth at the projection lies clearly in front
of the point (less than ``in_front`` times its depth) the point is hidden: what the track shows there says nothing
about the point. In the other frames inside the image the point is in view, and the track must be on it. A track
is that static point when

- it lies within ``px`` of the projection in at least ``frac`` of at least ``min_frames`` in-view frames, and
- at least ``min_hidden`` of its observations are off the point in frames where the point is hidden: the
  occluder explains what made it fail. Without this a slow mover the masks missed, explained by a static point in
  2D and caught by the depth tests, would be let go (a probe on `default` 0's saved result, stop 49: bg-mover
  recall 85.4 -> 81.2 without it, 85.3 with 2; ``docs/lifting.md``, item 4).

The track is then seen in its query frame and the in-view frames where it was on the point; its 2D track is the
point's projection (the hidden frames are not observations of the point). Why by hand: a per-track projection and
one depth lookup per frame; no library does this one job. Conventions: pixels x right / y down, OpenCV camera
axes, camera-to-world ``[T,4,4]`` poses.
"""

from __future__ import annotations

import numpy as np

from trackingworld.geometry import in_image, invert_pose, nearest_pixel, project, transform, unproject


def static_behind_occluders(uv: np.ndarray, vis: np.ndarray, qf: np.ndarray, z_q: np.ndarray, poses_c2w: np.ndarray,
                            K: np.ndarray, depth: np.ndarray, px: float = 2.0, frac: float = 0.8,
                            min_frames: int = 2, min_hidden: int = 2, in_front: float = 0.9):
    """Which tracks are static points hidden, where they stray, behind something nearer (module docstring).

    ``uv [n,T,2]`` px and ``vis [n,T]`` bool: the candidates' 2D tracks; ``qf [n]`` their query frames; ``z_q [n]``
    metres (camera z): the depth of each query pixel; ``poses_c2w [T,4,4]``; ``K [3,3]``; ``depth [T,H,W]`` metres:
    the consistent video depth, what each frame shows in front.

    Returns (static [n] bool; X [n,3] world metres, each query pixel's static point; of the m static ones, pixels
    [m,T,2] float32, their points' projections (the query pixel at the query frame), and seen [m,T] bool, the query
    frame and the in-view frames where the track was on its point)."""
    n, T = vis.shape
    ar = np.arange(n)
    uv_q = uv[ar, qf].astype(np.float64)
    X = transform(poses_c2w[qf], unproject(uv_q, np.asarray(z_q, np.float64), K))  # [n,3] world
    w2c = invert_pose(poses_c2w)
    in_view = np.zeros(n, np.int32)
    on_view = np.zeros(n, np.int32)
    hidden_off = np.zeros(n, np.int32)
    for t in range(T):
        v = np.flatnonzero(vis[:, t] & (qf != t))
        if not len(v):
            continue
        _, on, view, hidden = _look(X[v], uv[v, t], depth[t], w2c[t], K, px, in_front)
        in_view[v] += view
        on_view[v] += view & on
        hidden_off[v] += hidden & ~on
    static = (in_view >= min_frames) & (on_view >= frac * in_view) & (hidden_off >= min_hidden)
    keep = np.flatnonzero(static)
    pix = np.zeros((len(keep), T, 2), np.float32)
    seen = np.zeros((len(keep), T), bool)
    for t in range(T):
        pix[:, t], on, view, _ = _look(X[keep], uv[keep, t], depth[t], w2c[t], K, px, in_front)
        seen[:, t] = vis[keep, t] & on & view
    seen[np.arange(len(keep)), qf[keep]] = True
    pix[np.arange(len(keep)), qf[keep]] = uv_q[keep]
    return static, X, pix, seen


def _look(X: np.ndarray, uv_t: np.ndarray, depth_t: np.ndarray, w2c_t: np.ndarray, K: np.ndarray, px: float,
          in_front: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points ``X [m,3]`` (world) in one frame against the tracks' pixels there ``uv_t [m,2]``: (their projections
    [m,2] px; on [m], the track
    within ``px`` of the projection; in view [m], the projection inside the image, in front of the camera and not
    behind the frame's depth ``depth_t [H,W]``; hidden [m], inside the image with that depth less than ``in_front``
    times the point's)."""
    H, W = depth_t.shape
    c = transform(w2c_t, X)
    p, _ = project(c, K)
    z = c[:, 2]
    inside = (z > 0) & in_image(p, W, H)
    hidden = np.zeros(len(X), bool)
    k = np.flatnonzero(inside)
    x, y = nearest_pixel(p[k], W, H)
    hidden[k] = depth_t[y, x] < in_front * z[k]
    on = np.linalg.norm(p - uv_t, axis=-1) <= px
    return p, on, inside & ~hidden, hidden
