"""What each weight-free prior costs: the full method on a synthetic scene with the given (noisy) priors, with each
prior replaced by its weight-free default in turn, and with nothing but the video; plus the motion masks' quality.

    .venv/bin/python benchmarks/bench_priors.py --preset default      # writes benchmarks/results/priors_default.md
    .venv/bin/python benchmarks/bench_priors.py --grounded            # movers on the floor: priors_default_grounded.md

All rows share one set of dense 2D tracks (computed once). Depth and 3D metrics are scale-aligned by the
evaluation (Sim(3) from the camera trajectories; depth per the field's protocol), so an arbitrary-scale prior is
not penalised for its scale.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from _common import fmt, md_table_start, run_and_evaluate, scratch_dir, tracks_file, write_results  # noqa: I001 (a sibling script module)
from trackingworld.config import SFM_CONTACTS, InputConfig, OptimConfig, RunConfig, Track2DConfig
from trackingworld.io.frames import read_frames
from trackingworld.io.priors import load_masks
from trackingworld.synth import render_and_write
from trackingworld.synth.scene import PRESETS

# row: (method, depth, masks, intrinsics); "given" = the scene's noisy prior file, None = weight-free default
ROWS = {
    "given priors": ("trackingworld", "given", "given", "given"),
    "motion masks (weight-free)": ("trackingworld", "given", None, "given"),
    "SfM depth (weight-free)": ("trackingworld", None, "given", "given"),
    "assumed intrinsics (60 deg)": ("trackingworld", "given", "given", None),
    "all weight-free (video only)": ("trackingworld", None, None, None),
    "baseline, given priors": ("baseline", "given", "given", "given"),
    "baseline, video only": ("baseline", None, None, None),
}


def mask_quality(masks: np.ndarray, gt: dict) -> dict:
    dyn, bg = gt["dynamic"], gt["bg_mover"]
    inter = (masks & dyn).sum()
    return {"iou": float(inter / max((masks | dyn).sum(), 1)), "recall": float(inter / max(dyn.sum(), 1)),
            "precision": float(inter / max(masks.sum(), 1)),
            "bg_mover_recall": float((masks & bg).sum() / max(bg.sum(), 1))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--preset", default="default", choices=sorted(PRESETS))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--grounded", action="store_true",
                    help="the movers stand on the floor (SceneConfig.grounded_movers), as the SfM depth's contact "
                         "rule assumes; the presets' movers float")
    ap.add_argument("--sfm-contact", default=SFM_CONTACTS[0], choices=SFM_CONTACTS,
                    help="the SfM depth's rule for the dynamic regions (InputConfig.sfm_contact)")
    ap.add_argument("--keep", action="store_true", help="keep the scratch folder of scenes, tracks and runs")
    a = ap.parse_args(argv)
    work = scratch_dir("bench_priors_", a.keep)
    scene = render_and_write(work / "scene", a.preset, a.seed, grounded_movers=a.grounded)
    inp = scene / "input"
    frames, _ = read_frames(str(inp / "frames"))
    t0 = time.perf_counter()
    tracks = tracks_file(scene, work / "tracks.npz")
    track_s = time.perf_counter() - t0
    given = {"depth": str(inp / "depth.npy"), "masks": str(inp / "masks"), "intrinsics": str(inp / "intrinsics.txt")}
    gt = dict(np.load(scene / "gt.npz"))
    results = {}
    for name, (method, *specs) in ROWS.items():
        keys = ("depth", "masks", "intrinsics")
        kw = {k: (given[k] if s == "given" else s) for k, s in zip(keys, specs, strict=True)}
        cfg = RunConfig(method=method, inputs=InputConfig(input=str(inp / "frames"), sfm_contact=a.sfm_contact, **kw),
                        track2d=Track2DConfig(tracker="file", tracks_file=str(tracks)),
                        optim=OptimConfig(verbose=False))
        out = work / f"run{len(results)}"
        results[name] = {**run_and_evaluate(cfg, out, scene, name),
                         "priors": json.loads((out / "priors.json").read_text())}
        mm = out / "priors" / "masks_motion.npz"
        if mm.exists():
            results[name]["masks"] = mask_quality(np.load(mm)["masks"].astype(bool), gt)
    coarse = mask_quality(load_masks(inp / "masks", frames.shape[0]), gt)
    write(results, coarse, a.preset, frames.shape, track_s, a.seed, a.grounded, a.sfm_contact)
    return 0


def write(results: dict, coarse: dict, preset: str, shape, track_s: float, seed: int = 0,
          grounded: bool = False, contact: str = SFM_CONTACTS[0]) -> None:
    head = ("| priors | ATE [% path] | track depth AbsRel | video depth AbsRel | world 3D acc all / dyn | "
            "static kept [%] | bg-mover recall [%] | priors [s] | run [s] |")
    lines = md_table_start(
        f"# Weight-free priors on the `{preset}` scene, seed {seed}{', movers on the floor' if grounded else ''} "
        f"({shape[0]} frames, {shape[2]}x{shape[1]})",
        f"Command: `.venv/bin/python benchmarks/bench_priors.py --preset {preset}"
        f"{f' --seed {seed}' if seed else ''}{' --grounded' if grounded else ''}"
        f"{f' --sfm-contact {contact}' if contact != SFM_CONTACTS[0] else ''}` (dense 2D tracks computed "
        f"once, {track_s:.1f} s, shared by every row; run time excludes them)", head)
    for name, r in results.items():
        m = r["metrics"]
        c, td, vd, w, lab = m["camera"], m["track_depth"], m["video_depth"], m["world_3d"], m["labels"]
        lines.append(
            f"| {name} | {fmt(c['ate_pct_path'], 2)} | {fmt(td['abs_rel_depth'], 4)} | "
            f"{fmt(vd['abs_rel_depth'], 4)} | {fmt(w['all']['acc_avg'], 1)} / {fmt(w['dynamic']['acc_avg'], 1)} | "
            f"{fmt(lab['static_kept_static'], 1)} | {fmt(lab['bg_mover_recall'], 1)} | "
            f"{r['timings'].get('priors', 0):.1f} | {r['wall_s']:.1f} |")
    lines += ["", f"The raw depth prior's track depth AbsRel on the same pixels: "
              f"{fmt(results['given priors']['metrics']['track_depth_prior']['abs_rel_depth'], 4)}.", "",
              "Dynamic masks against the ground-truth moving pixels:", "",
              "| masks | IoU | recall | precision | recall on the movers the coarse masks miss |",
              "|---|---|---|---|---|",
              f"| coarse masks given with the scene | {coarse['iou']:.3f} | {coarse['recall']:.3f} | "
              f"{coarse['precision']:.3f} | {coarse['bg_mover_recall']:.3f} |"]
    mq = next((r["masks"] for r in results.values() if "masks" in r), None)
    if mq:
        lines.append(f"| motion masks (weight-free) | {mq['iou']:.3f} | {mq['recall']:.3f} | {mq['precision']:.3f} | "
                     f"{mq['bg_mover_recall']:.3f} |")
    name = (f"priors_{preset}" + (f"_seed{seed}" if seed else "") + ("_grounded" if grounded else "")
            + (f"_{contact}" if contact != SFM_CONTACTS[0] else ""))
    write_results(name, lines, results)


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
