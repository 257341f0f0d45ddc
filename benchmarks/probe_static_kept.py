"""Where the static tracks labelled dynamic come from: the result's tracks whose query pixel is static in the
ground truth, split by whether that pixel lies inside the given coarse masks, and by how the 2D tracker followed
them (seen in one frame only; seen in more and within 2 px of the static point through their query pixel over
every visible frame; straying further, ``eval.dense.static_deviation``), each with the share of them that ends
dynamic. The 2D tracks are judged as the tracker gave them: ``SCENE/tracks.npz`` (where ``bench_scenes.py`` keeps
them), not the result's visibility, which no longer shows the observations it found off a static point.
Separates what the labeller loses (tracks the 2D tracker kept on their point) from what the tracker hands it
(tracks that slid off their point, mostly at a mover's edge). A second table follows the tracks that stray and
end dynamic: how many of their seen frames are off the point, how soon after the query frame they leave it, in
how many of the frames off it a nearer surface hides the point (ground truth), and for how many the photometric
test of ``pipeline.static_side.photo_rescue`` (the result's video depth at the query pixel) has fewer than its
minimum of frames to test.

    .venv/bin/python benchmarks/probe_static_kept.py bench_out/scenes/run_default13_0 bench_out/scenes/default13

Writes ``benchmarks/results/probe_static_kept_<scene>.md`` (and prints it).
"""

from __future__ import annotations

import sys

import numpy as np

from _common import probe_inputs, query_pixels, write_results  # noqa: I001 (a sibling script module)
from trackingworld.config import OptimConfig
from trackingworld.eval.dense import static_deviation, static_points
from trackingworld.geometry import in_image, invert_pose, nearest_pixel, project, transform
from trackingworld.image import blurred_frames
from trackingworld.io.frames import read_frames
from trackingworld.io.priors import load_masks
from trackingworld.io.tracks import load_tracks
from trackingworld.optim.labels import mask_regions
from trackingworld.optim.photo_static import MASK_MARGIN_PX, colour_shares, depth_scales

ON_POINT_PX = 2.0  # a track within this of its static point over every visible frame followed it
HIDDEN = 0.97  # the ground-truth depth at the point's projection below this times the point's: a surface hides it


def off_point(tracks, visible, query_frame, gt) -> tuple[np.ndarray, np.ndarray]:
    """Per track and frame ``[N,T]``: the track more than ON_POINT_PX from the projection of the ground-truth
    point under its query pixel, and that point hidden by a nearer surface (inside the image)."""
    N, T = visible.shape
    depth, K = gt["depth"], gt["K"]
    H, W = depth.shape[1:]
    X, _ = static_points(tracks, query_frame, depth, gt["poses_c2w"], K)
    w2c = invert_pose(gt["poses_c2w"])
    off, hidden = np.zeros((N, T), bool), np.zeros((N, T), bool)
    for t in range(T):
        uv, z = project(transform(w2c[t], X), K)
        off[:, t] = np.linalg.norm(uv - tracks[:, t], axis=-1) > ON_POINT_PX
        px, py = nearest_pixel(uv, W, H)
        hidden[:, t] = in_image(uv, W, H) & (depth[t, py, px] < HIDDEN * z)
    return off & visible, hidden


def main(argv=None) -> int:
    run, scene, res, gt = probe_inputs(__doc__, argv)
    T, N, q = res.depth.shape[0], res.num_tracks, res.query_frame
    x, y = query_pixels(res)
    static = ~gt["dynamic"][q, y, x]
    masked = load_masks(scene / "input" / "masks", T)[q, y, x]
    given = load_tracks(scene / "tracks.npz", T)  # the 2D tracker's own visibility
    if given.visible.shape != res.visible.shape:
        raise SystemExit(f"{scene / 'tracks.npz'}: {given.visible.shape[0]} tracks, the result has {N}")
    dev = static_deviation(given.tracks, given.visible, q, gt["depth"], gt["poses_c2w"], gt["K"])
    seen = given.visible.sum(1)
    lost = static & res.is_dynamic
    n = int(static.sum())
    lines = [f"# Static tracks labelled dynamic: `{scene.name}`", "",
             f"Command: `.venv/bin/python benchmarks/probe_static_kept.py {run} {scene}`", "",
             f"Static tracks (query pixel static in the ground truth): {n:,}; labelled dynamic "
             f"{100 * lost.sum() / n:.2f}% (static kept {100 - 100 * lost.sum() / n:.2f}).", "",
             "| query pixel | 2D track | share of the static tracks [%] | labelled dynamic [% of them] | "
             "points of static kept lost |", "|---|---|---|---|---|"]
    on_point = dev <= ON_POINT_PX
    kinds = (("seen in one frame", seen < 2), (f"within {ON_POINT_PX:g} px of its point", (seen >= 2) & on_point),
             (f"strays more than {ON_POINT_PX:g} px", (seen >= 2) & ~on_point))
    for where, inside in (("inside the masks", masked), ("outside", ~masked)):
        for what, kind in kinds:
            s = static & inside & kind
            if s.any():
                lines.append(f"| {where} | {what} | {100 * s.sum() / n:.2f} | {100 * res.is_dynamic[s].mean():.1f} | "
                             f"{100 * (s & lost).sum() / n:.2f} |")
    cfg = OptimConfig()
    off, hidden = off_point(given.tracks, given.visible, q, gt)
    blur = blurred_frames(read_frames(str(scene / "input" / "frames"))[0])
    open_ = mask_regions(load_masks(scene / "input" / "masks", T), MASK_MARGIN_PX)[0]
    lines += ["", "The static tracks that stray more than 2 px and end dynamic:", "",
              "| query pixel | tracks | seen frames (median) | of them off the point [%] | first frame off, from the "
              "query (median) | of the frames off, the point hidden [%] | photometric test: no frame / fewer than "
              f"{cfg.photo_static_frames} [%] |", "|---|---|---|---|---|---|---|"]
    for where, inside in (("inside the masks", masked), ("outside", ~masked)):
        idx = np.flatnonzero(static & inside & (seen >= 2) & ~on_point & res.is_dynamic)
        if not len(idx):
            continue
        o = off[idx]
        first = np.array([np.abs(np.flatnonzero(r) - t).min() for r, t in zip(o, q[idx], strict=True)])
        _, count, _, _ = colour_shares(given.tracks[idx, q[idx]], res.depth[q[idx], y[idx], x[idx]].astype(np.float64),
                                       q[idx], res.poses_c2w, res.intrinsics, blur, open_, cfg.photo_static_grey,
                                       depth_scales(cfg.photo_static_range), res.depth, cfg.occluded_static_depth)
        lines.append(f"| {where} | {len(idx):,} | {np.median(seen[idx]):.0f} | "
                     f"{100 * np.median(o.sum(1) / seen[idx]):.0f} | {np.median(first):.0f} | "
                     f"{100 * (o & hidden[idx]).sum() / o.sum():.0f} | {100 * np.mean(count == 0):.0f} / "
                     f"{100 * np.mean(count < cfg.photo_static_frames):.0f} |")
    write_results(f"probe_static_kept_{scene.name}", lines, {"lines": lines})
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
