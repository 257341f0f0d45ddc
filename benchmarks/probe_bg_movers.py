"""Which tracks on the movers the masks missed end labelled static: the result's tracks whose query pixel lies on
a background mover, by how far their 2D track strays from the static point through their query pixel (px,
``eval.dense.static_deviation``, the ground truth's geometry) and how many frames they are seen in; with the
camera depth of the static-labelled ones at their query frame against the ground truth (does the depth show them?).

    .venv/bin/python benchmarks/probe_bg_movers.py bench_out/scenes/run_default12_0 bench_out/scenes/default12

Writes ``benchmarks/results/probe_bg_movers_<scene>.md`` (and prints it).
"""

from __future__ import annotations

import sys

import numpy as np

from _common import probe_inputs, query_pixels, write_results  # noqa: I001 (a sibling script module)
from trackingworld.eval.dense import static_deviation
from trackingworld.geometry import invert_pose, transform

DEVIATION_BINS = ((0, 2), (2, 4), (4, 8), (8, np.inf))  # px


def main(argv=None) -> int:
    run, scene, res, gt = probe_inputs(__doc__, argv)
    q = res.query_frame
    x, y = query_pixels(res)
    on = gt["bg_mover"][q, y, x]
    dev = static_deviation(res.tracks_2d, res.visible, q, gt["depth"], gt["poses_c2w"], gt["K"])
    seen = res.visible.sum(1)
    cam = gt["poses_c2w"][:, :3, 3]
    bg = gt["tracks_bg_mover"]
    moved = gt["tracks_xyz"][bg][:, -1] - gt["tracks_xyz"][bg][:, 0]
    lines = [f"# Tracks on the movers the masks missed: `{scene.name}`", "",
             f"Command: `.venv/bin/python benchmarks/probe_bg_movers.py {run} {scene}`", "",
             f"Camera path {np.linalg.norm(np.diff(cam, axis=0), axis=1).sum():.2f} m; the ground-truth query tracks "
             f"on background movers ({int(bg.sum())}) move {np.median(np.linalg.norm(moved, axis=1)):.2f} m over the "
             f"video (median). Result tracks on them: {int(on.sum()):,}, labelled dynamic "
             f"{100 * res.is_dynamic[on].mean():.1f}%.", "",
             "| deviation from a static point [px] | tracks | labelled dynamic [%] | median frames seen |",
             "|---|---|---|---|"]
    for lo, hi in DEVIATION_BINS:
        s = on & (dev >= lo) & (dev < hi)
        if s.any():
            lines.append(f"| {lo}-{'' if np.isinf(hi) else hi} | {s.sum():,} | {100 * res.is_dynamic[s].mean():.1f} | "
                         f"{np.median(seen[s]):.0f} |")
    missed = on & ~res.is_dynamic
    if missed.any():
        z = transform(invert_pose(res.poses_c2w)[q[missed]], res.tracks_3d[np.flatnonzero(missed), q[missed]])[:, 2]
        r = z / gt["depth"][q[missed], y[missed], x[missed]]
        p10, p50, p90 = np.percentile(r, [10, 50, 90])
        lines += ["", f"Those labelled static: camera depth at the query frame over the true depth {p50:.3f} (median; "
                  f"p10 {p10:.3f}, p90 {p90:.3f}); seen in {np.median(seen[missed]):.0f} frames (median); query "
                  f"frame 0 for {100 * (q[missed] == 0).mean():.0f}% of them."]
    write_results(f"probe_bg_movers_{scene.name}", lines, {"lines": lines})
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
