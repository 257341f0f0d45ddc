"""Where the static tracks labelled dynamic come from: the result's tracks whose query pixel is static in the
ground truth, split by whether that pixel lies inside the given coarse masks, and by how the 2D tracker followed
them (seen in one frame only; seen in more and within 2 px of the static point through their query pixel over
every visible frame; straying further, ``eval.dense.static_deviation``), each with the share of them that ends
dynamic. The 2D tracks are judged as the tracker gave them: ``SCENE/tracks.npz`` (where ``bench_scenes.py`` keeps
them), not the result's visibility, which no longer shows the observations it found off a static point.
Separates what the labeller loses (tracks the 2D tracker kept on their point) from what the tracker hands it
(tracks that slid off their point, mostly at a mover's edge).

    .venv/bin/python benchmarks/probe_static_kept.py bench_out/scenes/run_default13_0 bench_out/scenes/default13

Writes ``benchmarks/results/probe_static_kept_<scene>.md`` (and prints it).
"""

from __future__ import annotations

import sys

import numpy as np

from _common import probe_inputs, query_pixels, write_results  # noqa: I001 (a sibling script module)
from trackingworld.eval.dense import static_deviation
from trackingworld.io.priors import load_masks
from trackingworld.io.tracks import load_tracks

ON_POINT_PX = 2.0  # a track within this of its static point over every visible frame followed it


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
    write_results(f"probe_static_kept_{scene.name}", lines, {"lines": lines})
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
