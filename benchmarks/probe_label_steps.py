"""Which step of the lifting set the wrong labels: the result's tracks (their query pixel on the ground truth's
maps) by the step that last changed their label (``result.npz``'s ``label_step``, ``optim.label_steps``), counting
the static tracks labelled dynamic (what static kept loses), the tracks on the movers the masks missed labelled
static (what bg-mover recall loses) and the tracks on the masked movers labelled static. A second table splits the
tracks no step changed (``masks``) by the frames they are seen in: a track seen in one frame shows no motion to any
test, one seen in more was looked at by the static side's tests (stage 2 or its rebuild) and kept.

    .venv/bin/python benchmarks/probe_label_steps.py bench_out/scenes/run_default17_0 bench_out/scenes/default17

Writes ``benchmarks/results/probe_label_steps_<scene>.md`` (and prints it).
"""

from __future__ import annotations

import sys

import numpy as np

from _common import probe_inputs, query_pixels, write_results  # noqa: I001 (a sibling script module)
from trackingworld.errors import InputError
from trackingworld.optim.label_steps import LABEL_STEPS

SEEN_BINS = (("1", 1, 1), ("2-3", 2, 3), ("4-9", 4, 9), ("10-", 10, 1 << 30))  # (label, first, last) frames seen


def main(argv=None) -> int:
    run, scene, res, gt = probe_inputs(__doc__, argv)
    if res.label_step is None:
        raise InputError(f"{run}: the result has no label_step (a baseline run, or one written before stop 76)")
    q = res.query_frame
    x, y = query_pixels(res)
    bg = gt["bg_mover"][q, y, x]
    masked = gt["dynamic"][q, y, x] & ~bg
    static = ~gt["dynamic"][q, y, x] & ~bg
    dyn = res.is_dynamic
    classes = (("static labelled dynamic", static, dyn), ("missed-mover tracks labelled static", bg, ~dyn),
               ("masked-mover tracks labelled static", masked, ~dyn))
    lines = [f"# Which step set the wrong labels: `{scene.name}`", "",
             f"Command: `.venv/bin/python benchmarks/probe_label_steps.py {run} {scene}`", "",
             "Each track counts once, under the last step that changed its label (`masks`: none did). In brackets: "
             "the share of the ground truth's class (static / on a missed mover / on a masked mover) that step got "
             "wrong.", "",
             "| step | " + " | ".join(name for name, _, _ in classes) + " |",
             "|---|" + "---|" * len(classes)]
    data = {}
    for code, step in enumerate(LABEL_STEPS):
        mine = res.label_step == code
        cells, row = [], {}
        for name, truth, wrong in classes:
            n = int((mine & truth & wrong).sum())
            row[name] = n
            share = 100 * n / max(int(truth.sum()), 1)
            cells.append(f"{n:,} ({share:.2f}%)" if n else "-")
        data[step] = row
        if any(row.values()):
            lines.append(f"| {step} | " + " | ".join(cells) + " |")
    totals = []
    for _, truth, wrong in classes:
        n = int((truth & wrong).sum())
        totals.append(f"{n:,} of {int(truth.sum()):,} ({100 * n / max(int(truth.sum()), 1):.2f}%)")
    lines.append("| all | " + " | ".join(totals) + " |")
    seen = res.visible.sum(1)
    untouched = res.label_step == LABEL_STEPS.index("masks")
    lines += ["", "The tracks no step changed (`masks`), by the frames they are seen in:", "",
              "| frames seen | " + " | ".join(name for name, _, _ in classes) + " |",
              "|---|" + "---|" * len(classes)]
    by_seen = {}
    for label, lo, hi in SEEN_BINS:
        inside = untouched & (seen >= lo) & (seen <= hi)
        by_seen[label] = [int((inside & truth & wrong).sum()) for _, truth, wrong in classes]
        lines.append(f"| {label} | " + " | ".join(f"{n:,}" if n else "-" for n in by_seen[label]) + " |")
    write_results(f"probe_label_steps_{scene.name}", lines, {"lines": lines, "by_step": data, "masks_by_seen": by_seen})
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
