"""Dynamic-labelled tracks that are static points the 2D tracker dragged: the static hypothesis checked in the images.

Beside a mover, DIS's flow leaks into the background, and a background point's 2D track is dragged along with the
mover from its first frames (stop 43's probe: 11% of `default` 2's static tracks lie inside the coarse masks and
stray more than 2 px from their point, and 43% of those end dynamic). No test on the 2D track can tell it from the
mover's own tracks: both move with the mover. The images can. The track's query pixel is lifted at its depth
(the field-corrected prior, a few scales around it), that static point is projected into every other frame, and
its colour there is compared with its query colour. Only the frames where the projection falls outside the
(dilated) coarse masks count, and outside them the static hypothesis predicts the point's own background:

- a background point matches its query colour in nearly all of them;
- a point on a mover does not: once the mover has gone, the projection lands on whatever the background holds.

With ``patch_grey`` > 0 a frame matches only where the 5x5 patch around the projection (its mean removed) is
also within ``patch_grey`` of the query pixel's, on the mean over the patch: one pixel's colour does not tell a
background point from a mover that slides a few pixels over a smooth texture, its patch does.

Where the track itself is seen in a tested frame farther from the projection than a distance (``track``'s; 2 px
in the pipeline, ``OptimConfig.photo_static_track_px``), the two hypotheses point at different pixels, and a
projection that shows the query colour is evidence for the static point only if it shows it better than the
track's own pixel does: on a mover with a smooth texture both pixels show it, and the frame does not count as
matched (stop 61: on `default` 24 the test took 124 tracks of the mover the masks missed for static points; in 93%
of their frames seen off the projection the track's own pixel matched the query colour at least as well, against
8% for the 1,484 static tracks it took back, whose own pixel had been dragged off it).

A track that matches in at least ``frac`` of at least ``min_frames`` such frames is that static point. Its 2D
track becomes the point's projection and it is visible in the query frame and the frames it matched. Why by hand:
it is a per-track plane-sweep of one pixel over a handful of depths, a few array operations per frame; no library
does this one job. Conventions: ``uv [n,2]`` px (x right, y down), poses camera-to-world ``[T,4,4]``, OpenCV axes.
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from trackingworld.geometry import in_image, invert_pose, nearest_pixel, project, transform, unproject
from trackingworld.image import patch_offsets, sample_image, sample_patches

# the frames where the point lies within this many px of the coarse masks do not count: the test reads the masks'
# sure-static region (optim.labels.mask_regions with this margin)
MASK_MARGIN_PX = 2
# at most this many frames are tested, evenly strided over the video: the test's cost grows with the candidates
# times the frames, both of which grow with the video. The 120-frame video: 1.6 s with every frame, 0.57 s with 32;
# at 32, the five 48-frame `hard` scenes kept 0.0-0.7 points fewer static tracks static than with every frame
MAX_TESTED_FRAMES = 48
PATCH_RADIUS = 2  # the patch test's half-side (px): 5x5, the 2D tracker's patch for the points it finds again


def depth_scales(span: float, step: float = 0.02) -> np.ndarray:
    """The depth scales tried along a query ray: 1 - ``span`` to 1 + ``span`` in steps of about ``step``
    (0.04: 0.96, 0.98, 1, 1.02, 1.04)."""
    k = int(round(span / step))
    return 1.0 + step * np.arange(-k, k + 1) if k > 0 else np.ones(1)


def near_masks(uv: np.ndarray, vis: np.ndarray, masks: np.ndarray, px: float) -> np.ndarray:
    """``[n]`` bool: the tracks (``uv [n,T,2]`` px, ``vis [n,T]``) seen within ``px`` of the coarse ``masks [T,H,W]``
    in some frame (cv2.distanceTransform of each frame's complement)."""
    n, T = vis.shape
    out = np.zeros(n, bool)
    for t in range(T):
        v = np.flatnonzero(vis[:, t] & ~out)
        if not len(v) or not masks[t].any():
            continue
        dist = cv2.distanceTransform((~masks[t]).astype(np.uint8), cv2.DIST_L2, 3)
        x, y = nearest_pixel(uv[v, t], masks.shape[2], masks.shape[1])
        out[v[dist[y, x] <= px]] = True
    return out


def _look(X: np.ndarray, colour: np.ndarray, blur_t: np.ndarray, open_t: np.ndarray, w2c_t: np.ndarray,
          K: np.ndarray, grey: float, depth_t: np.ndarray | None = None, in_front: float = 0.9,
          patch: tuple[np.ndarray, float] | None = None,
          own: tuple[np.ndarray, np.ndarray, float] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World points ``X [n,3]`` seen by one camera (``w2c_t [4,4]``, blurred frame ``blur_t [H,W,3]``, open region
    ``open_t [H,W]``): (pixels [n,2] float32; tested [n] bool: in front of the camera, in the image, in the open
    region and, with the frame's depth ``depth_t [H,W]`` metres, not hidden (that depth at least ``in_front`` times
    the point's); matched [n] bool: tested and within ``grey`` of ``colour [n,3]``, max over RGB, and with
    ``patch`` (the query patches [n,P,3] of :func:`query_patches`, a tolerance in grey levels) the patch there
    within that tolerance of its query patch, on the mean absolute difference; with ``own`` (the tracks' pixels
    [n,2] px in this frame, whether they are seen there [n] bool, a distance px) a point whose track is seen more than
    that distance from its projection matches only where the projection's colour is nearer the query colour than
    the track's own pixel's is)."""
    uv, tested = _project_and_test(X, w2c_t, K, open_t, depth_t, in_front)
    idx = np.flatnonzero(tested)
    matched = np.zeros(len(X), bool)
    diff = np.abs(sample_image(blur_t, uv[idx]).astype(np.float32) - colour[idx]).max(1)
    matched[idx] = diff <= grey
    if own is not None:  # seen elsewhere: the projection must show the query colour better than the track does
        own_uv, own_seen, off_px = own
        away = matched[idx] & own_seen[idx] & (np.linalg.norm(own_uv[idx] - uv[idx], axis=1) > off_px)
        a = idx[away]
        if len(a):
            own_diff = np.abs(sample_image(blur_t, own_uv[a].astype(np.float32)).astype(np.float32) - colour[a]).max(1)
            matched[a] = diff[away] < own_diff
    idx = np.flatnonzero(matched)
    if patch is not None and len(idx):
        patches, tol = patch
        offs = patch_offsets(PATCH_RADIUS)
        matched[idx] = np.abs(sample_patches(blur_t, uv[idx], offs) - patches[idx]).mean((1, 2)) <= tol
    return uv, tested, matched


def _project_and_test_numpy(X, w2c_t, K, open_t, depth_t, in_front):
    """:func:`_look`'s projections (float32 [n,2] px) and which of them are tested [n] bool, in numpy: the
    reference of :func:`_project_and_test`."""
    H, W = open_t.shape
    uv, z = project(transform(w2c_t, X), K, eps=1e-9)
    uv = uv.astype(np.float32)
    tested = (z > 1e-9) & in_image(uv, W, H, margin=0.5)
    x, y = nearest_pixel(uv, W, H)
    tested &= open_t[y, x]
    if depth_t is not None:
        tested &= depth_t[y, x] >= in_front * z
    return uv, tested


@njit(cache=True, error_model="numpy")
def _project_and_test_kernel(X, T, k, open_t, depth_t, has_depth, in_front):
    """:func:`_project_and_test_numpy` in one pass over the points (float64 points and pose):
    numpy's operations in numpy's order, so the same pixels and flags to the last bit."""
    n = len(X)
    H, W = open_t.shape
    uv = np.empty((n, 2), np.float32)
    tested = np.zeros(n, np.bool_)
    hi_u, hi_v = np.float32(W - 1.0), np.float32(H - 1.0)
    zero = np.float32(0.0)
    for i in range(n):
        x0, x1, x2 = X[i, 0], X[i, 1], X[i, 2]
        c0 = x0 * T[0, 0] + x1 * T[0, 1] + x2 * T[0, 2] + T[0, 3]
        c1 = x0 * T[1, 0] + x1 * T[1, 1] + x2 * T[1, 2] + T[1, 3]
        z = x0 * T[2, 0] + x1 * T[2, 1] + x2 * T[2, 2] + T[2, 3]
        zs = 1e-9 if abs(z) < 1e-9 else z
        u = np.float32(k[0, 0] * c0 / zs + k[0, 2])
        v = np.float32(k[1, 1] * c1 / zs + k[1, 2])
        uv[i, 0] = u
        uv[i, 1] = v
        if not (z > 1e-9 and u >= zero and u <= hi_u and v >= zero and v <= hi_v):
            continue
        px = min(max(int(np.rint(u)), 0), W - 1)
        py = min(max(int(np.rint(v)), 0), H - 1)
        if not open_t[py, px]:
            continue
        if has_depth and not (np.float64(depth_t[py, px]) >= in_front * z):
            continue
        tested[i] = True
    return uv, tested


def _project_and_test(X, w2c_t, K, open_t, depth_t, in_front):
    """:func:`_look`'s projections (float32 [n,2] px) and which of them are tested [n] bool: by
    :func:`_project_and_test_kernel` for float64 points and pose (the pipeline's), else by the numpy reference. The
    numpy version makes [n,3] temporaries of every point in every tested frame; with the kernel the two
    photometric stages took 7.6 -> 3.3 s at 854x480 (docs/speed.md, stop 71)."""
    if not (X.dtype == w2c_t.dtype == np.float64 and (depth_t is None or depth_t.dtype in (np.float32, np.float64))):
        return _project_and_test_numpy(X, w2c_t, K, open_t, depth_t, in_front)
    has_depth = depth_t is not None
    d = depth_t if has_depth else np.zeros((1, 1), np.float32)
    return _project_and_test_kernel(np.ascontiguousarray(X), np.ascontiguousarray(w2c_t), np.asarray(K, np.float64),
                                    open_t, d, has_depth, float(in_front))


def _tally(X: np.ndarray, qf: np.ndarray, colour: np.ndarray, blur: np.ndarray, open_: np.ndarray,
           w2c: np.ndarray, K: np.ndarray, grey: float, depth: np.ndarray | None = None,
           in_front: float = 0.9, patch: tuple[np.ndarray, float] | None = None,
           track: tuple[np.ndarray, np.ndarray, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(frames tested [n], frames matched [n]) of the static points ``X [n,3]`` (query frames ``qf [n]``, query
    colours ``colour [n,3]`` float32) over every frame but the query frame, strided to at most MAX_TESTED_FRAMES
    (:func:`_look`; ``depth [T,H,W]``: the frames where a point is hidden are not tested; ``patch``: the patch
    test's query patches and tolerance; ``track``: the 2D tracks [n,T,2] px, their visibility [n,T] and the
    distance px beyond which a frame where the track is seen away from the projection needs the better colour)."""
    tested = np.zeros(len(X), np.int32)
    matched = np.zeros(len(X), np.int32)
    T = len(open_)
    for t in range(0, T, -(-T // MAX_TESTED_FRAMES)):
        _, ok, same = _look(X, colour, blur[t], open_[t], w2c[t], K, grey, None if depth is None else depth[t],
                            in_front, patch, _own_at(track, t))
        other = qf != t
        tested += ok & other
        matched += same & other
    return tested, matched


def _own_at(track: tuple[np.ndarray, np.ndarray, float] | None, t: int):
    """The ``own`` argument of :func:`_look` for frame ``t``: ``track`` (uv [n,T,2] px, vis [n,T], px) at that
    frame; None without a track."""
    if track is None:
        return None
    uv, vis, px = track
    return uv[:, t], vis[:, t], px


def _at_queries(uv_q: np.ndarray, qf: np.ndarray, blur: np.ndarray, sample, shape: tuple) -> np.ndarray:
    """``[n,*shape]`` float32: ``sample(frame, pixels)`` of each query pixel ``uv_q [n,2]`` in its query frame
    ``qf [n]`` of ``blur [T,H,W,3]``, one call per query frame."""
    out = np.zeros((len(qf), *shape), np.float32)
    for t in np.unique(qf):
        who = np.flatnonzero(qf == t)
        out[who] = sample(blur[t], uv_q[who].astype(np.float32))
    return out


def query_colours(uv_q: np.ndarray, qf: np.ndarray, blur: np.ndarray) -> np.ndarray:
    """``[n,3]`` float32: the blurred frames' ``blur [T,H,W,3]`` colour at each query pixel ``uv_q [n,2]`` of its
    query frame ``qf [n]`` (bilinear)."""
    return _at_queries(uv_q, qf, blur, sample_image, (3,))


def query_patches(uv_q: np.ndarray, qf: np.ndarray, blur: np.ndarray) -> np.ndarray:
    """``[n,P,3]`` float32: the blurred frames' ``blur [T,H,W,3]`` patch of PATCH_RADIUS around each query pixel
    ``uv_q [n,2]`` of its query frame ``qf [n]``, each patch's mean removed (bilinear)."""
    offs = patch_offsets(PATCH_RADIUS)
    return _at_queries(uv_q, qf, blur, lambda img, p: sample_patches(img, p, offs), (len(offs), 3))


def colour_shares(uv_q: np.ndarray, z_q: np.ndarray, qf: np.ndarray, poses_c2w: np.ndarray, K: np.ndarray,
                  blur: np.ndarray, open_: np.ndarray, grey: float = 12.0, scales: np.ndarray | None = None,
                  depth: np.ndarray | None = None, in_front: float = 0.9, patch_grey: float = 0.0,
                  track: tuple[np.ndarray, np.ndarray, float] | None = None):
    """How well each query pixel's static point shows its query colour (the arguments as
    :func:`static_hypothesis`'s): at each depth scale tried, the share of its tested frames that match; the best
    scale kept (the share, then the count; on a tie the scale nearest 1).

    Returns (share [n] of the tested frames matched, count [n] of frames tested, X [n,3] world metres at the best
    scale, colour [n,3] float32 the query colours)."""
    n = len(qf)
    scales = depth_scales(0.04) if scales is None else np.asarray(scales, np.float64)
    scales = scales[np.argsort(np.abs(np.log(scales)), kind="stable")]  # on a tie the scale nearest 1 is kept
    w2c = invert_pose(poses_c2w)
    colour = query_colours(uv_q, qf, blur)
    patch = (query_patches(uv_q, qf, blur), patch_grey) if patch_grey > 0 else None
    cam = unproject(uv_q.astype(np.float64), z_q, K)  # [n,3] each query pixel at its depth, its camera's axes

    def points(s):  # world points at the depth scales s [n]
        return transform(poses_c2w[qf], cam * s[:, None])

    best = np.full(n, -1.0)  # the choice: the share of tested frames matched, then the count
    best_s = np.ones(n)
    share = np.zeros(n)
    count = np.zeros(n, np.int32)
    for s in scales:
        tested, matched = _tally(points(np.full(n, s)), qf, colour, blur, open_, w2c, K, grey, depth, in_front,
                                 patch, track)
        f = matched / np.maximum(tested, 1)
        better = f + 1e-4 * matched > best
        best[better] = (f + 1e-4 * matched)[better]
        best_s[better], share[better], count[better] = s, f[better], tested[better]
    return share, count, points(best_s), colour


def static_hypothesis(uv_q: np.ndarray, z_q: np.ndarray, qf: np.ndarray, poses_c2w: np.ndarray, K: np.ndarray,
                      blur: np.ndarray, open_: np.ndarray, grey: float = 12.0, frac: float = 0.8,
                      min_frames: int = 3, scales: np.ndarray | None = None, depth: np.ndarray | None = None,
                      in_front: float = 0.9, patch_grey: float = 0.0,
                      track: tuple[np.ndarray, np.ndarray, float] | None = None):
    """Which tracks are static points by their colours (module docstring).

    ``uv_q [n,2]`` px and ``z_q [n]`` metres (camera z): each track's query pixel and its depth estimate;
    ``qf [n]`` query frames; ``poses_c2w [T,4,4]``; ``K [3,3]``; ``blur [T,H,W,3]`` uint8
    (``trackingworld.image.blurred_frames``); ``open_ [T,H,W]`` bool, where the hypothesis is tested (the
    masks' sure-static region: ``optim.labels.mask_regions`` with MASK_MARGIN_PX); ``grey``: colour tolerance
    (grey levels, max over RGB); ``frac``, ``min_frames``: the share of at least that many tested frames (every
    frame but the query frame, strided to at most MAX_TESTED_FRAMES) that must match; ``scales``: the depth scales
    tried along the query ray (default 0.96-1.04 in 5 steps), the best match fraction kept; ``depth [T,H,W]``
    metres (the consistent video depth; None: not read): a frame where it is less than ``in_front`` times the
    point's depth at the projection hides the point there, and is not tested; ``patch_grey`` > 0: a frame matches
    only where its patch does too; ``track`` (the 2D tracks uv [n,T,2] px, vis [n,T] bool, a distance px): a frame
    where the track is seen farther than that from the projection matches only where the projection shows the
    query colour better than the track's pixel does (module docstring; None: the projection alone).

    Returns (static [n] bool; X [n,3] world metres at the best scale; of the m static ones, pixels [m,T,2]
    float32, their points' projections (the query pixel at the query frame), and seen [m,T] bool, the query frame
    and the tested frames that matched)."""
    T = len(poses_c2w)
    share, count, X, colour = colour_shares(uv_q, z_q, qf, poses_c2w, K, blur, open_, grey, scales, depth, in_front,
                                            patch_grey, track)
    w2c = invert_pose(poses_c2w)
    static = (count >= min_frames) & (share >= frac)
    keep = np.flatnonzero(static)
    pix = np.zeros((len(keep), T, 2), np.float32)
    seen = np.zeros((len(keep), T), bool)
    patch = (query_patches(uv_q[keep], qf[keep], blur), patch_grey) if patch_grey > 0 else None
    track_kept = None if track is None else (track[0][keep], track[1][keep], track[2])  # the static ones' rows, once
    for t in range(T):
        pix[:, t], _, seen[:, t] = _look(X[keep], colour[keep], blur[t], open_[t], w2c[t], K, grey,
                                         None if depth is None else depth[t], in_front, patch, _own_at(track_kept, t))
    seen[np.arange(len(keep)), qf[keep]] = True
    pix[np.arange(len(keep)), qf[keep]] = uv_q[keep]
    return static, X, pix, seen
