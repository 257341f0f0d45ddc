"""How far the 2D tracks drift from the truth with the frames from their query frame, on the static scene and on
the movers apart: the ground-truth query tracks read from the result's 2D tracks as the metrics read them
(``eval.match``: the nearest tracks at the query pixel), their pixel error in the frames both the truth and the
result see them, median and 80th percentile per span of frames from the query frame. A rigid group's motion is
fitted to its 2D tracks and turns their drift into a motion distorted in depth (``probe_group_depth.py``,
docs/results.md stop 95).

    .venv/bin/python benchmarks/probe_drift.py bench_out/scenes/run_hard0_0 bench_out/scenes/hard0

RUN is a ``trackingworld run`` output folder, SCENE the synthetic scene it was run on. Writes
``benchmarks/results/probe_drift_<scene>.md`` (and prints it).
"""

from __future__ import annotations

import sys

import numpy as np

from _common import probe_inputs, write_results  # noqa: I001 (a sibling script module)
from trackingworld.eval.match import match_queries

SPANS = ((1, 4), (4, 8), (8, 16), (16, 32), (32, 64), (64, 10**6))  # frames from the query frame, [lo, hi)


def main(argv=None) -> int:
    run, scene, res, gt = probe_inputs(__doc__, argv)
    qf = gt["query_frame"]
    m = match_queries(res.tracks_2d, res.visible, res.tracks_3d, res.is_dynamic, qf, gt["query_uv"])
    T = res.visible.shape[1]
    apart = np.abs(np.arange(T)[None] - qf[:, None])
    seen = gt["tracks_vis"].astype(bool) & m.visible & m.found[:, None]
    err = np.linalg.norm(m.uv - gt["tracks_uv"], axis=-1)
    dyn, bg = gt["tracks_dynamic"].astype(bool), gt["tracks_bg_mover"].astype(bool)
    kinds = {"static scene": ~dyn, "masked movers": dyn & ~bg, "missed movers": bg}
    spans = [(lo, hi) for lo, hi in SPANS if lo < T]
    head = " | ".join(f"{lo}-{hi - 1 if hi < 10**6 else ''} frames" for lo, hi in spans)
    lines = [f"# 2D drift from the query frame: `{scene.name}`", "",
             f"Command: `.venv/bin/python benchmarks/probe_drift.py {run} {scene}`", "",
             "Pixel error of the ground-truth query tracks read from the result (median / 80th percentile, px; the "
             "observations seen in both), by frames from the query frame.", "",
             f"| queries | {head} |", "|---" * (len(spans) + 1) + "|"]
    data = {}
    for name, sel in kinds.items():
        if not sel.any():
            continue
        cells, data[name] = [], []
        for lo, hi in spans:
            k = seen & sel[:, None] & (apart >= lo) & (apart < hi)
            if k.any():
                med, p80 = np.median(err[k]), np.percentile(err[k], 80)
                cells.append(f"{med:.2f} / {p80:.2f} ({int(k.sum()):,})")
                data[name].append({"frames": [lo, hi], "median_px": float(med), "p80_px": float(p80),
                                   "observations": int(k.sum())})
            else:
                cells.append("-")
        lines.append(f"| {name} ({int(sel.sum())}) | " + " | ".join(cells) + " |")
    write_results(f"probe_drift_{scene.name}", lines, data)
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
