"""The 2D tracker's optical flow against the ground-truth flow of a synthetic scene, with and without the
colour-guided weighted median (``tracking2d.flow_tracker.weighted_median``, ``--flow-median``): end-point error
(px) over the non-occluded pixels, in the band within 6 px of a motion boundary (where the ground-truth flow's
Sobel gradient exceeds 4 px / px) and beyond it, and the share of the band off by more than 1 / 2 px.

    .venv/bin/python benchmarks/probe_flow_median.py bench_out/scenes/default0 bench_out/scenes/default2

Each SCENE is a folder written by ``trackingworld synth`` (``bench_scenes.py`` keeps them in its cache); its
``gt.npz`` holds the flow between one pair of frames (``flow_frames``: frames 6 -> 0 in the synthetic scenes, six
frames apart, so larger motion than the tracker's one-frame steps: a median 21 px on ``default`` 0, 33 px on
``hard`` 0, which DIS gets wrong far from any boundary too). The flows are the tracker's own (``pairwise_flows``,
default DIS settings) over that pair. Writes ``benchmarks/results/probe_flow_median.md`` (and prints it).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np
from scipy import ndimage

from _common import md_table_start, write_results  # noqa: I001 (a sibling script module)
from trackingworld.io.frames import read_frames
from trackingworld.tracking2d.flow_tracker import pairwise_flows

BAND_PX = 6  # a pixel this close to a motion boundary is in the band
BOUNDARY_GRAD = 4.0  # Sobel gradient of the ground-truth flow (px / px, unnormalised 3x3) that marks a boundary
SETTINGS = (("DIS (default)", (0, 10.0, 0.5)), ("median r3, gated 0.5 px", (3, 10.0, 0.5)),
            ("median r5, gated 0.5 px (--flow-median 5)", (5, 10.0, 0.5)), ("median r5, everywhere", (5, 10.0, 0.0)))


def epe_row(flow: np.ndarray, gt: np.ndarray, valid: np.ndarray, band: np.ndarray) -> dict:
    """End-point errors of ``flow [H,W,2]`` against ``gt`` over ``valid``, in ``band`` and beyond it."""
    e = np.linalg.norm(flow - gt, axis=-1)
    b, far = valid & band, valid & ~band
    return {"all": float(e[valid].mean()), "band": float(e[b].mean()), "far": float(e[far].mean()),
            "band_over_1px": 100 * float((e[b] > 1).mean()), "band_over_2px": 100 * float((e[b] > 2).mean())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", type=Path, nargs="+")
    a = ap.parse_args(argv)
    command = f"Command: `.venv/bin/python benchmarks/probe_flow_median.py {' '.join(map(str, a.scenes))}`"
    lines = md_table_start("# The tracker's flow near motion boundaries, with and without the weighted median", command,
                           "| scene | flow | EPE all [px] | EPE in the band [px] | band > 1 px [%] | band > 2 px [%] "
                           "| EPE beyond [px] | s per flow |")
    data: dict = {}
    for scene in a.scenes:
        gt = np.load(scene / "gt.npz")
        t0, t1 = (int(t) for t in gt["flow_frames"])
        frames, _ = read_frames(str(scene / "input" / "frames"))
        pair = [frames[t0], frames[t1]]
        gray = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in pair]
        g = gt["flow"]
        grad = np.maximum(*(np.abs(ndimage.sobel(g[..., c], 0)) + np.abs(ndimage.sobel(g[..., c], 1)) for c in (0, 1)))
        band = ndimage.distance_transform_edt(grad <= BOUNDARY_GRAD) <= BAND_PX
        valid = ~gt["flow_occluded"].astype(bool)
        for name, median in SETTINGS:
            t = time.perf_counter()
            flow = pairwise_flows(gray, guide=pair, median=median)[0][0]
            r = {**epe_row(flow, g, valid, band), "seconds": time.perf_counter() - t}
            data.setdefault(scene.name, {})[name] = r
            lines.append(f"| {scene.name} | {name} | {r['all']:.3f} | {r['band']:.3f} | {r['band_over_1px']:.1f} | "
                         f"{r['band_over_2px']:.1f} | {r['far']:.3f} | {r['seconds']:.2f} |")
            print(f"[probe] {scene.name} {name}", file=sys.stderr, flush=True)
    lines += ["", f"Band: non-occluded pixels within {BAND_PX} px of a motion boundary of the ground-truth flow; "
              "'s per flow': DIS plus the filter, one forward flow."]
    write_results("probe_flow_median", lines, data)
    return 0


if __name__ == "__main__":
    sys.exit(main())
