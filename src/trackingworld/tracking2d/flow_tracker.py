"""A weight-free tracker: OpenCV DIS optical flow between consecutive frames, chained over time in both
directions from each query frame.

A step is observed when the forward-backward flow check passes, the (slightly blurred) colour at the new
position matches the old one, and the point stays in the image. A point that fails a step (occluded, or its
flow is unreliable) is carried by the median displacement of the neighbours that moved like it before the
gap and are still observed (a support grid is tracked with every query frame so that sparse queries have
neighbours too); it is found again when the flow there agrees with that prediction, and its position is then
re-anchored by pyramidal Lucas-Kanade against its patch in the query frame, which removes the error the
prediction accumulated through the gap. Where the flow does not agree (it often smooths across the occluder
that just left), the point is also looked for directly: Lucas-Kanade from the query patch, started at the
predicted position, finds it when the window matches closely and the colour there is the query colour.
Positions in frames where a point is not visible are these predictions, not observations; they are kept
(not held at the last observed position) because they are the better guess of where the point is.

Drift: every chained step adds a little error (on a 120-frame synthetic scene 0.05 px median after one step,
0.5 px after 30, 0.9 px after 60). Flows over ``skip_stride`` frames between the frames that are multiples of it
(a quarter more flow to compute) bound it: at each such frame a point observed in every frame since the
previous one is placed by the longer flow from its position there, so that over a long span the error of one
long step adds up once per ``skip_stride`` frames instead of every frame (0.47 px after 60 frames at stride 4).

Smoothed flow drags a background point along with an object that passes close by, and the way back agrees, so
the forward-backward check passes. Where the flow varies within ``drag_window_px`` (motion boundaries), a step
that leaves the median step of the neighbours that moved like the point by more than ``drag_abs_px`` +
``drag_rel`` of it is not observed; the point is carried through it like any gap. On the 32-frame ``default``
scene (seed 0) the static tracks that stray more than 2 px from their point fall from 17.6% to 15.1%.

Chained flow also lets a point slide slowly off its surface point, which no single step's checks see. A point
whose colour has moved more than ``max_query_colour_diff`` from its colour in the query frame is lost from
there on; in dense tracking the pixels it covered become uncovered and get a fresh track from that frame.

Every flow goes through a colour-guided weighted median where it differs from the median by more than
``median_gate_px`` (``median_radius``; 0: off), which puts motion boundaries back on colour edges: more static
tracks stay on their point beside movers and the movers' tracks drift less, at 1.4x the tracking time at 854x480
and 1.8x at 320x240 (docs/tracking2d.md)."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from trackingworld import reproducible
from trackingworld.errors import InputError
from trackingworld.geometry import nearest_pixel
from trackingworld.image import blurred_frames, patch_offsets, sample_image, sample_patches
from trackingworld.progress import Progress
from trackingworld.tracking2d.base import TrackResult


@dataclass
class FlowTrackerConfig:
    preset: str = "fine"  # DIS preset: ultrafast | fast | medium | fine
    # the fine preset's DIS patches (px): side and stride. Smaller patches leak less of a moving object's flow
    # into the background beside it (docs/tracking2d.md; 8 and 3 before)
    patch_size: int = 4
    patch_stride: int = 2
    fb_abs_px: float = 2.0  # forward-backward error allowed: abs + rel * |flow|
    fb_rel: float = 0.05
    max_colour_diff: float = 10.0  # grey levels (0-255, max over RGB, sigma-1 blur) a step may change; 0: off
    max_gap: int = 16  # frames a point may stay unobserved before it is lost for good
    neighbours: int = 8  # neighbours that carry a point through a gap
    min_neighbours: int = 2  # fewer observed neighbours: the point keeps its last velocity
    neighbour_radius: float = 0.075  # of the image's longer side
    max_candidates: int = 4096  # observed points the neighbours are picked from (evenly thinned)
    neighbour_vel_abs_px: float = 0.5  # neighbours move like the point: |dv| < abs + rel * |v| (smoothed v)
    neighbour_vel_rel: float = 0.1
    velocity_smoothing: float = 0.5  # exponential smoothing of the observed velocity
    support_spacing: float = 0.025  # support grid tracked with every query frame, of the longer side; 0: none
    relocate_win: int = 15  # Lucas-Kanade window (px) that re-anchors a point found after a gap; 0: off
    relocate_levels: int = 2
    relocate_max_shift_px: float = 16.0
    relocate_max_err: float = 20.0  # mean absolute grey difference over the window
    refind: bool = True  # a point in a gap is also looked for by Lucas-Kanade at its predicted position
    refind_max_err: float = 8.0  # ... and found when the window matches its query patch this well
    refind_win: int = 11
    # an observed point whose colour has left its query colour by more than this (grey levels, max over RGB,
    # sigma-1 blur) has slipped off its surface point and is lost, so that a fresh track takes its place; 0: off
    max_query_colour_diff: float = 25.0
    # a point found again after a gap (re-anchored or re-found) whose (2 patch_radius + 1)^2 patch of sigma-1 blurred
    # colour differs from its patch in the query frame by more than this (grey levels: mean absolute difference over
    # the patch and RGB, each patch's mean colour removed) stays in its gap. Off (0) by default: it keeps static
    # tracks on their point but costs the missed movers' recall (docs/tracking2d.md, stop 48)
    refind_patch_diff: float = 0.0
    patch_radius: int = 2
    # flows over this many frames between its multiples re-place the points observed throughout (drift); 0: off
    skip_stride: int = 4
    skip_max_shift_px: float = 2.0  # ... unless they move a point further than this from its chained position
    # an observed step that leaves the median step of the neighbours that moved like the point by more than
    # abs + rel * |step| px is not observed (a point dragged along by the flow of an object passing it); 0: off
    drag_abs_px: float = 0.5
    drag_rel: float = 0.1
    drag_window_px: int = 6  # ... tested only where a flow component varies by drag_abs_px within this many px
    # every pairwise flow goes through OpenCV's weighted median filter guided by the source frame's colours (radius
    # px; 0: off): DIS smooths a mover's flow into the background beside it, the median puts the motion boundary
    # back on the colour edge (Sun, Roth & Black, "Secrets of optical flow", 2010). Needs opencv-contrib. On the
    # 96 synthetic scenes world accuracy and static kept up, at 1.4-1.8x the tracking time (docs/tracking2d.md)
    median_radius: int = 5
    median_sigma: float = 10.0  # ... its colour weights' width (grey levels)
    median_gate_px: float = 0.5  # ... taken only where it differs from DIS's flow by more than this (0: everywhere)
    verbose: bool = False


def _dis(preset: str, patch: tuple[int, int]):
    """OpenCV DIS flow. ``fine`` is the ``medium`` preset at full resolution with smaller, denser patches
    (``patch``: side and stride in px)."""
    presets = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
               "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM, "fine": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}
    if preset not in presets:
        raise ValueError(f"unknown DIS preset {preset!r} (choose from {', '.join(presets)})")
    dis = cv2.DISOpticalFlow_create(presets[preset])
    if preset == "fine":
        dis.setFinestScale(0)
        dis.setPatchSize(patch[0])
        dis.setPatchStride(patch[1])
        dis.setGradientDescentIterations(40)
        dis.setVariationalRefinementIterations(10)
    return dis


def _need_ximgproc() -> None:
    if not hasattr(cv2, "ximgproc"):
        raise InputError("the flow's weighted median needs OpenCV's contrib modules (cv2.ximgproc): pip install "
                         "opencv-contrib-python-headless in place of opencv-python-headless, or pass "
                         "--flow-median 0")


def weighted_median(flow: np.ndarray, guide: np.ndarray, radius: int, sigma: float, gate: float = 0.0) -> np.ndarray:
    """``flow [H,W,2]`` through OpenCV's weighted median filter (``cv2.ximgproc``, opencv-contrib) of half-side
    ``radius`` px, each neighbour weighted by a Gaussian of width ``sigma`` (grey levels) in its colour difference
    in ``guide [H,W,3]`` uint8: a flow that leaks across a colour edge is replaced by the flow of the pixel's side.
    With ``gate`` > 0 the median replaces the flow only where they differ by more than ``gate`` px: elsewhere
    the median's steps (it picks one neighbour's value) would bias a smoothly varying flow.

    The filter clusters the guide's colours from a random start (OpenCV's RNG): seeded here, so that the same
    frames give the same flow (unseeded, two calls differ by up to 6 px on a tenth of the pixels)."""
    _need_ximgproc()
    chans = []
    for c in range(2):
        cv2.setRNGSeed(0)
        chans.append(cv2.ximgproc.weightedMedianFilter(guide, np.ascontiguousarray(flow[..., c]), radius, sigma))
    med = np.stack(chans, -1)
    if gate <= 0:
        return med
    return np.where((np.linalg.norm(med - flow, axis=-1) > gate)[..., None], med, flow)


def pairwise_flows(gray: list, preset: str = "fine", verbose: bool = False, stride: int = 1,
                   patch: tuple[int, int] = (FlowTrackerConfig.patch_size, FlowTrackerConfig.patch_stride),
                   guide: list | None = None, median: tuple[int, float, float] = (0, 10.0, 0.5)):
    """Forward flows ``fwd[j]`` (frame j s -> (j+1) s) and backward flows ``bwd[j]`` ((j+1) s -> j s), each
    [(T-1) // s,H,W,2], of the grey frames ``gray`` (T x [H,W] uint8), s = ``stride`` (1: consecutive frames);
    ``patch``: the fine preset's DIS patch side and stride (px); ``median``: radius (px, 0: off), colour width and
    gate of the :func:`weighted_median` each flow goes through, guided by its source frame in ``guide`` (T x
    [H,W,3] uint8).

    With more than one OpenCV thread (``cv2.getNumThreads``; ``--threads 1`` makes it one) the medians run on one
    thread of their own beside the flows of the next pairs: the filter runs on one core, and DIS gains little from
    a second, so the two overlap (``docs/speed.md``, stop 96). One thread, not more: two filters at once corrupt
    each other's memory (OpenCV 5.0). The same flows either way: each filter seeds its own thread's RNG."""
    radius, sigma, gate = median
    if radius > 0:
        if guide is None:
            raise ValueError("the flow's weighted median needs the colour frames (guide)")
        _need_ximgproc()
    dis = _dis(preset, patch)
    n = max((len(gray) - 1) // stride, 0)
    fwd = np.zeros((n,) + gray[0].shape + (2,), np.float32)
    bwd = np.zeros_like(fwd)
    bar = Progress("track2d: optical flow pair" + (f" {stride} frames apart" if stride > 1 else ""), n, verbose)

    def medians(j: int, a: int, b: int) -> None:
        fwd[j] = weighted_median(fwd[j], guide[a], radius, sigma, gate)
        bwd[j] = weighted_median(bwd[j], guide[b], radius, sigma, gate)

    def medians_beside(j: int, a: int, b: int) -> None:  # OpenCV's IPP switch is per thread: set as the caller's
        reproducible.follow()  # block wants it, as optim.parallel.each_frame's threads do
        medians(j, a, b)

    beside = ThreadPoolExecutor(1) if radius > 0 and cv2.getNumThreads() > 1 else None
    jobs: list = []
    shown = 0

    def show(k: int) -> None:  # pairs whose flows are final
        nonlocal shown
        if k > shown:
            shown = k
            bar.update(k)

    try:
        for j in range(n):
            a, b = j * stride, (j + 1) * stride
            fwd[j] = dis.calc(gray[a], gray[b], None)
            bwd[j] = dis.calc(gray[b], gray[a], None)
            if beside is not None:
                jobs.append(beside.submit(medians_beside, j, a, b))
            elif radius > 0:
                medians(j, a, b)
            show(sum(f.done() for f in jobs) if beside is not None else j + 1)
        for k, f in enumerate(jobs):
            f.result()
            show(k + 1)
    finally:
        if beside is not None:
            beside.shutdown(cancel_futures=True)
    return fwd, bwd


def sample_flow(flow: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Bilinear sample of ``flow [H,W,2]`` at ``pts [M,2]``."""
    return sample_image(flow, pts)


@dataclass
class _Video:
    """What the tracker computes once per video: pairwise flows, grey frames (for Lucas-Kanade) and
    sigma-1 blurred colour frames (for the colour check), all at the frames' resolution."""

    key: int
    fwd: np.ndarray  # [T-1,H,W,2]
    bwd: np.ndarray  # [T-1,H,W,2]
    gray: list  # T x [H,W] uint8
    blur: np.ndarray  # [T,H,W,3] uint8
    skip_fwd: np.ndarray  # [J,H,W,2]: flow from frame j s to (j + 1) s (s = skip_stride; J = 0 when off)
    skip_bwd: np.ndarray  # [J,H,W,2]: from (j + 1) s back to j s
    varied_fwd: np.ndarray | None = None  # [T-1,H,W] bool: the forward flow varies nearby (drag check); None: off
    varied_bwd: np.ndarray | None = None


def flow_varies(flows: np.ndarray, tol: float, radius: int) -> np.ndarray:
    """``[n,H,W]`` bool: where a component of ``flows [n,H,W,2]`` ranges over more than ``tol`` px within the
    square of half-side ``radius`` px (grey-level dilation minus erosion): near motion boundaries and in
    strongly varying flow, the only places a point can be dragged off its neighbours' motion."""
    box = np.ones((2 * radius + 1,) * 2, np.uint8)
    out = np.zeros(flows.shape[:3], bool)
    for j, f in enumerate(flows):
        out[j] = (cv2.dilate(f, box) - cv2.erode(f, box) > tol).any(-1)
    return out


def pick_neighbours(p: np.ndarray, vel: np.ndarray, who: np.ndarray, cand: np.ndarray, k: int, radius: float,
                    vel_abs: float, vel_rel: float) -> np.ndarray:
    """For the points ``who`` up to ``k`` of the points ``cand`` (indices into ``p [M,2]``) within ``radius``
    px whose velocity ``vel [M,2]`` is close to theirs. Returns ``[len(who),k]`` indices, -1 where none."""
    out = np.full((len(who), k), -1, np.int64)
    if not len(cand) or not len(who) or k == 0:
        return out
    kk = min(2 * k, len(cand))
    d, j = cKDTree(p[cand]).query(p[who], k=kk, distance_upper_bound=radius)
    d, j = d.reshape(len(who), kk), j.reshape(len(who), kk)
    jj = cand[np.minimum(j, len(cand) - 1)]
    valid = np.isfinite(d)
    dv = np.linalg.norm(vel[jj] - vel[who][:, None], axis=-1)
    valid &= dv < vel_abs + vel_rel * np.linalg.norm(vel[who], axis=1)[:, None]
    order = np.argsort(~valid, axis=1, kind="stable")[:, :k]
    jj = np.take_along_axis(jj, order, 1)
    valid = np.take_along_axis(valid, order, 1)
    out[:, : jj.shape[1]] = np.where(valid, jj, -1)
    return out


class FlowTracker:
    """Chained optical flow with occlusion handling, in both directions of time from each query frame.

    See the module docstring for the rules; after ``max_gap`` failed steps in a row, or once it leaves the
    image, a point is lost for good. Positions where a point is not visible are the tracker's estimate
    (neighbour-carried or constant velocity), not observations.
    """

    def __init__(self, config: FlowTrackerConfig | None = None):
        self.config = config or FlowTrackerConfig()
        self._video: _Video | None = None

    def _prepare(self, frames: np.ndarray) -> _Video:
        if self._video is None or self._video.key != id(frames):
            gray = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames]
            c = self.config
            patch, med = (c.patch_size, c.patch_stride), (c.median_radius, c.median_sigma, c.median_gate_px)
            fwd, bwd = pairwise_flows(gray, c.preset, c.verbose, patch=patch, guide=frames, median=med)
            if c.skip_stride > 1:
                skip_fwd, skip_bwd = pairwise_flows(gray, c.preset, c.verbose, c.skip_stride, patch, frames, med)
            else:
                skip_fwd = skip_bwd = np.zeros((0,) + fwd.shape[1:], np.float32)
            self._video = _Video(id(frames), fwd, bwd, gray, blurred_frames(frames), skip_fwd, skip_bwd)
            if c.drag_abs_px > 0:
                self._video.varied_fwd = flow_varies(fwd, c.drag_abs_px, c.drag_window_px)
                self._video.varied_bwd = flow_varies(bwd, c.drag_abs_px, c.drag_window_px)
        return self._video

    def flows(self, frames: np.ndarray):
        """Forward and backward pairwise flows ``[T-1,H,W,2]`` of ``frames`` (computed once per video)."""
        v = self._prepare(frames)
        return v.fwd, v.bwd

    def _relocate(self, video: _Video, t_src: int, p_src: np.ndarray, t_dst: int, q: np.ndarray,
                  max_err: float | None = None, win: int | None = None):
        """Refine positions ``q [M,2]`` in frame ``t_dst`` by pyramidal Lucas-Kanade from the points' patches
        at ``p_src [M,2]`` in frame ``t_src``. Returns the positions ``[M,2]`` and success ``[M]`` (converged,
        mean absolute grey difference below ``max_err``, default ``relocate_max_err``, shift bounded)."""
        c = self.config
        r, st, er = cv2.calcOpticalFlowPyrLK(
            video.gray[t_src], video.gray[t_dst], p_src.reshape(-1, 1, 2).astype(np.float32),
            q.reshape(-1, 1, 2).astype(np.float32).copy(), winSize=(win or c.relocate_win,) * 2,
            maxLevel=c.relocate_levels, flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 10, 0.03))
        r = r.reshape(-1, 2)
        good = (st.ravel() == 1) & (er.ravel() < (c.relocate_max_err if max_err is None else max_err))
        good &= np.linalg.norm(r - q, axis=1) < c.relocate_max_shift_px
        return np.where(good[:, None], r, q), good

    def _step(self, flow_a: np.ndarray, flow_b: np.ndarray, p: np.ndarray):
        """Points ``p [M,2]`` moved by ``flow_a [H,W,2]``: (displacement [M,2], new positions [M,2], whether the
        way back by ``flow_b`` returns within the forward-backward tolerance [M])."""
        c = self.config
        fa = sample_flow(flow_a, p)
        q = p + fa
        err = np.linalg.norm(fa + sample_flow(flow_b, q), axis=1)
        return fa, q, err < c.fb_abs_px + c.fb_rel * np.linalg.norm(fa, axis=1)

    def _neighbours(self, p: np.ndarray, va: np.ndarray, who: np.ndarray, cand: np.ndarray, k: int,
                    radius: float) -> np.ndarray:
        """:func:`pick_neighbours` of the points ``who`` among ``cand`` evenly thinned to at most
        ``max_candidates`` (a kd-tree is built every step), with the config's velocity tolerance."""
        c = self.config
        cand = cand[:: max(1, -(-len(cand) // c.max_candidates))]
        return pick_neighbours(p, va, who, cand, k, radius, c.neighbour_vel_abs_px, c.neighbour_vel_rel)

    def _dragged(self, p: np.ndarray, va: np.ndarray, fa: np.ndarray, obs: np.ndarray, test: np.ndarray, k: int,
                 radius: float) -> np.ndarray:
        """[M] bool: of the points ``test``, those whose step ``fa [M,2]`` leaves the median step of up to ``k``
        observed points (``obs``) within ``radius`` px that moved like them (smoothed velocity ``va``)."""
        c = self.config
        out = np.zeros(len(p), bool)
        who = np.flatnonzero(test)
        cand = np.flatnonzero(obs)
        if not len(who) or len(cand) < 2:
            return out
        nb = self._neighbours(p, va, who, cand, k, radius)
        nb = np.where(nb == who[:, None], -1, nb)
        has = nb >= 0
        enough = has.sum(1) >= max(c.min_neighbours, 3)
        med = np.nanmedian(np.where(has[..., None], fa[np.maximum(nb, 0)], np.nan)[enough], axis=1)
        d = np.linalg.norm(fa[who[enough]] - med, axis=1)
        out[who[enough]] = d > c.drag_abs_px + c.drag_rel * np.linalg.norm(med, axis=1)
        return out

    def _propagate(self, video: _Video, p0: np.ndarray, t0: int, direction: int, tracks, vis, sel) -> None:
        """Track ``p0 [M,2]`` from frame ``t0`` one way in time; writes the first ``len(sel)`` points into
        ``tracks[sel]`` / ``vis[sel]`` (the rest are support points)."""
        c = self.config
        T, H, W = video.blur.shape[:3]
        flows_a, flows_b = (video.fwd, video.bwd) if direction == 1 else (video.bwd, video.fwd)
        M, K = len(p0), c.neighbours
        radius = c.neighbour_radius * max(H, W)
        p = p0.copy()
        v = np.zeros_like(p)  # last step
        va = np.zeros_like(p)  # smoothed velocity of the observed steps
        gap = np.zeros(M, int)
        lost = np.zeros(M, bool)
        nbr = np.full((M, K), -1, np.int64)  # neighbours carrying a point through its gap
        nbr_ref = np.zeros((M, K, 2), np.float32)  # their positions when the gap began
        p_ref = p.copy()  # the point's last observed position
        refind = c.refind and c.relocate_win > 0
        drift_check = c.max_query_colour_diff > 0
        # the query colour: what a point found again must match, and what an observed point must stay near
        c_query = sample_image(video.blur[t0], p0).astype(np.float32) if refind or drift_check else None
        offs = patch_offsets(c.patch_radius) if c.refind_patch_diff > 0 else None
        patch_query = sample_patches(video.blur[t0], p0, offs) if offs is not None else None

        def looks_like_query(who: np.ndarray, at: np.ndarray, frame: int) -> np.ndarray:
            """[len(who)] bool: the points ``who``'s patches at ``at [len(who),2]`` in ``frame`` are within
            ``refind_patch_diff`` of their query patches (all true when the test is off)."""
            if offs is None or not len(who):
                return np.ones(len(who), bool)
            d = np.abs(sample_patches(video.blur[frame], at, offs) - patch_query[who]).mean((1, 2))
            return d <= c.refind_patch_diff
        s = c.skip_stride if len(video.skip_fwd) else 0
        skip_a, skip_b = (video.skip_fwd, video.skip_bwd) if direction == 1 else (video.skip_bwd, video.skip_fwd)
        # the last multiple of s passed, and every point's position there
        anchor_t, anchor_p = (t0, p0.copy()) if s and t0 % s == 0 else (None, None)
        run = np.zeros(M, int)  # steps observed at both ends in a row
        t = t0
        while 0 <= t + direction < T:
            k = t if direction == 1 else t - 1  # index of the flow between t and t + direction
            fa, q, ok = self._step(flows_a[k], flows_b[k], p)
            ok &= ~lost
            cb = None
            if c.max_colour_diff > 0:
                ca = sample_image(video.blur[t], p).astype(np.float32)
                cb = sample_image(video.blur[t + direction], q).astype(np.float32)
                ok &= np.abs(ca - cb).max(1) < c.max_colour_diff
            moved = np.zeros(M, bool)  # points whose position in the next frame is not the flow's
            in_gap = gap > 0
            if c.drag_abs_px > 0 and t != t0:
                varied = (video.varied_fwd if direction == 1 else video.varied_bwd)[k]
                xi, yi = nearest_pixel(p, W, H)
                ok &= ~self._dragged(p, va, fa, ok & ~in_gap, ok & ~in_gap & varied[yi, xi], K, radius)
            carriers = ok & ~in_gap  # observed in both frames
            new = ~ok & ~in_gap & ~lost  # points whose gap begins now
            if new.any():
                who = np.flatnonzero(new)
                nbr[who] = self._neighbours(p, va, who, np.flatnonzero(carriers), K, radius)
                nbr_ref[who] = p[np.maximum(nbr[who], 0)]
                p_ref[who] = p[who]
            # prediction through a gap: the median displacement of the neighbours observed now
            pred = p + v
            gp = np.flatnonzero(in_gap | new)
            if gp.size:
                nb = nbr[gp]
                has = (nb >= 0) & carriers[np.maximum(nb, 0)]
                disp = np.where(has[..., None], q[np.maximum(nb, 0)] - nbr_ref[gp], np.nan)
                use = has.sum(1) >= c.min_neighbours
                if use.any():
                    pred[gp[use]] = p_ref[gp[use]] + np.nanmedian(disp[use], axis=1)
            # after a gap the flow must agree with the predicted step, and the point is re-anchored
            step = pred - p
            ok &= ~in_gap | (np.linalg.norm(fa - step, axis=1) < c.fb_abs_px + 0.25 * np.linalg.norm(step, axis=1))
            back = np.flatnonzero(ok & in_gap)
            if c.relocate_win and back.size:
                q[back], good = self._relocate(video, t0, p0[back], t + direction, q[back])
                good &= looks_like_query(back, q[back], t + direction)
                ok[back[~good]] = False
                moved[back] = True
            if refind:
                miss = np.flatnonzero(~ok & (in_gap | new) & ~lost)
                pm = pred[miss]
                miss = miss[(pm[:, 0] >= 0) & (pm[:, 0] < W) & (pm[:, 1] >= 0) & (pm[:, 1] < H)]
                if miss.size:
                    r, good = self._relocate(video, t0, p0[miss], t + direction, pred[miss], c.refind_max_err,
                                             c.refind_win)
                    c1 = sample_image(video.blur[t + direction], r).astype(np.float32)
                    good &= np.abs(c_query[miss] - c1).max(1) < c.max_colour_diff
                    good &= looks_like_query(miss, r, t + direction)
                    q[miss[good]] = r[good]
                    ok[miss[good]] = True
                    moved[miss[good]] = True
            tn = t + direction
            if s and tn % s == 0 and anchor_t == tn - direction * s:
                # drift: a point observed in every frame since the previous multiple of s is placed by the flow
                # over those s frames, when its forward-backward check passes and it moves the point little
                w = np.flatnonzero(ok & ~moved & (run >= s - 1))
                if w.size:
                    j = min(anchor_t, tn) // s
                    _, qs, good = self._step(skip_a[j], skip_b[j], anchor_p[w])
                    good &= np.linalg.norm(qs - q[w], axis=1) < c.skip_max_shift_px
                    q[w[good]] = qs[good]
                    moved[w[good]] = True
            p_new = np.where(ok[:, None], q, pred)
            v = np.where(ok[:, None], fa, p_new - p)
            smooth = 0.0 if t == t0 else c.velocity_smoothing
            va = np.where(carriers[:, None], smooth * va + (1 - smooth) * v, va)
            p = p_new
            inside = (p[:, 0] >= -0.5) & (p[:, 0] < W - 0.5) & (p[:, 1] >= -0.5) & (p[:, 1] < H - 0.5)
            gap = np.where(ok, 0, gap + 1)
            # steps observed at both ends in a row: a point found again starts a new run, its position at the
            # previous multiple of s (the skip flow's start) being the estimate it was carried at
            run = np.where(ok & ~in_gap, run + 1, 0)
            if s and tn % s == 0:
                anchor_t, anchor_p = tn, p.copy()
            if drift_check:  # the colour at the new position: sampled above unless the position moved since
                resample = np.flatnonzero(ok & moved) if cb is not None else np.flatnonzero(ok)
                c_new = cb if cb is not None else np.zeros_like(c_query)
                if resample.size:
                    c_new[resample] = sample_image(video.blur[t + direction], p[resample]).astype(np.float32)
                lost |= ok & (np.abs(c_new - c_query).max(1) > c.max_query_colour_diff)
            lost |= (gap > c.max_gap) | ~inside
            t += direction
            n = len(sel)
            tracks[sel, t] = p[:n]
            vis[sel, t] = (ok & inside & ~lost)[:n]

    def track(self, frames: np.ndarray, queries: np.ndarray) -> TrackResult:
        """Tracks ``[N,T,2]`` of ``queries [N,3]`` (t, x, y) in ``frames [T,H,W,3]``, both ways in time."""
        T, H, W = frames.shape[:3]
        video = self._prepare(frames)
        N = queries.shape[0]
        tracks = np.zeros((N, T, 2), np.float32)
        vis = np.zeros((N, T), bool)
        qt = queries[:, 0].round().astype(int)
        spacing = max(1, round(self.config.support_spacing * max(H, W)))
        for t0 in np.unique(qt):
            sel = np.flatnonzero(qt == t0)
            p0 = queries[sel, 1:3].astype(np.float32)
            tracks[sel, t0] = p0
            vis[sel, t0] = True
            if self.config.support_spacing > 0 and self.config.neighbours > 0:
                p0 = np.concatenate([p0, grid_queries(t0, H, W, spacing)[:, 1:].astype(np.float32)])
            self._propagate(video, p0, t0, 1, tracks, vis, sel)
            self._propagate(video, p0, t0, -1, tracks, vis, sel)
        return TrackResult(tracks, vis, vis.astype(np.float32), queries.astype(np.float32))


def grid_queries(t: int, H: int, W: int, stride: int, mask: np.ndarray | None = None) -> np.ndarray:
    """Queries ``[M,3]`` (t, x, y) on a regular grid of ``stride`` px, optionally where ``mask`` is set."""
    off = (stride - 1) / 2.0
    ys, xs = np.mgrid[off:H:stride, off:W:stride]
    xs, ys = xs.ravel(), ys.ravel()
    if mask is not None:
        keep = mask[ys.round().astype(int).clip(0, H - 1), xs.round().astype(int).clip(0, W - 1)]
        xs, ys = xs[keep], ys[keep]
    return np.stack([np.full(xs.shape, t, np.float64), xs, ys], 1)
