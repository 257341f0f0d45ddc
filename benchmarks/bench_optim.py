"""Benchmark of the world-centric optimiser (issue 4), run on demand:
``.venv/bin/python benchmarks/bench_optim.py [--preset default] [--quick]``, or over several scenes of a preset
``.venv/bin/python benchmarks/bench_optim.py --seeds 0 1 2 3`` (the full method and the baseline per seed, with
means: ``benchmarks/results/optim_<preset>_seeds.md``).

On one synthetic scene, with the same dense 2D tracks for every row (tracked once, then passed as a tracks
file), runs: the full method with the structured solver (default), the same with the paper's Adam schedule
(``--solver adam``), each ablation switch of the paper's table, the "w/o T.E.F" tracks, and the camera-centric
baseline. Reports ATE / RTE / RRE, track and video depth Abs Rel beside the raw prior on the same pixels,
world 3D accuracy (all / dynamic), labels, and the optimisation time of each row. Writes
``benchmarks/results/optim_<preset>.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from _common import OPT_STAGES, fmt, md_table_start, run_and_evaluate, scratch_dir, tracks_file, write_results  # noqa: I001 (a sibling script module)
from trackingworld.config import InputConfig, OptimConfig, RunConfig, Track2DConfig
from trackingworld.io.frames import read_frames
from trackingworld.synth import render_and_write
from trackingworld.synth.scene import PRESETS

# the settings of the paper / the authors' code where this package departs from them (README)
PAPER_LIKE = {"static_rebuild": "idw", "dc_target": "prior", "carry_k": 0, "mask_dynamic_px": 0.0,
              "depth_mover_log": 0.0, "prior_field": False, "static_refit_dc": 0.0, "own_test": False,
              "test_stat": "max", "static_outliers": False, "ts_order": 1, "slip_run": 0.0, "vote_short": 1,
              "dc_edge_sigma_px": 0.0, "stage2_reject": False, "vote_colour_sigma": 0.0,
              "vote_once_gap_px": float("inf"), "photo_static_grey": 0.0, "occluded_static_frames": 0,
              "dynamic_cell": 0, "photo_moving_share": 0.0, "rigid_movers": False}

# dense 2D tracks the rows run on (Track2DConfig fields)
TRACKS = {"": {}, "first": {"first_frame_only": True}, "mean": {"upsampler": "convex-mean"},
          "nodrag": {"flow_drag_px": 0.0}, "dis": {"flow_median": 0}}

ROWS = {
    "full (lm solver, default)": ("trackingworld", {}, ""),
    "full (adam, paper schedule)": ("trackingworld", {"solver": "adam"}, ""),
    "w/o T.E.F": ("trackingworld", {}, "first"),
    "w/o pose-init": ("trackingworld", {"no_pose_init": True}, ""),
    "w/o D.O.T": ("trackingworld", {"no_dynamic_opt": True}, ""),
    "w/o N_inliers": ("trackingworld", {"no_inliers": True}, ""),
    "w/o O_static": ("trackingworld", {"no_offsets": True}, ""),
    "w/o L_dc": ("trackingworld", {"no_depth_consistency": True}, ""),
    "dc on metres (paper as written)": ("trackingworld", {"dc_space": "metres"}, ""),
    "every static track optimised (no speed-up)": ("trackingworld", {"downsample_cell": 0}, ""),
    "static tracks rebuilt by IDW (appendix)": ("trackingworld", {"static_rebuild": "idw"}, ""),
    "stage-3 target = raw prior (paper)": ("trackingworld", {"dc_target": "prior"}, ""),
    "stage-3 target = per-frame median ratio": ("trackingworld", {"dc_target": "frame"}, ""),
    "stage-3 target = local ratio": ("trackingworld", {"dc_target": "local"}, ""),
    "prior as sampled at the depth edges (paper)": ("trackingworld", {"dc_edge_sigma_px": 0.0}, ""),
    "stage 2 solved once, every observation (paper)": ("trackingworld", {"stage2_reject": False}, ""),
    "stage-3 target field fitted frame by frame": ("trackingworld", {"dc_field_temporal": 0.0}, ""),
    "stage-3 target field: first differences at 0.001 (stops 41-51)": ("trackingworld", {"dc_target_order": 1,
                                                                             "dc_target_smooth": 0.001}, ""),
    "stage-3 target field as the static side's (before stop 41)": ("trackingworld", {"dc_target_order": 1,
                                                                                  "dc_target_smooth": 0.01}, ""),
    "hidden dynamic frames held": ("trackingworld", {"carry_k": 0}, ""),
    "hidden frames carried by the donors' weighted mean": ("trackingworld", {"carry_stat": "mean"}, ""),
    "stage-3 smoothness: first difference (paper)": ("trackingworld", {"ts_order": 1}, ""),
    "mask-dynamic test by offsets alone": ("trackingworld", {"mask_dynamic_px": 0.0}, ""),
    "no depth-discrepancy mover test (paper)": ("trackingworld", {"depth_mover_log": 0.0}, ""),
    "no static refit against the corrected prior (paper)": ("trackingworld", {"static_refit_dc": 0.0}, ""),
    "static fits against the raw prior, no refit (paper)": ("trackingworld", {"prior_field": False,
                                                                           "static_refit_dc": 0.0}, ""),
    "static tracks judged by the neighbours' vote alone (appendix)": ("trackingworld", {"own_test": False}, ""),
    "tracks outside stage 2 tested by their largest offset (paper)": ("trackingworld", {"test_stat": "max"}, ""),
    "static observations off their point kept": ("trackingworld", {"static_outliers": False}, ""),
    "masked tracks that slip off their point: no run test (paper)": ("trackingworld", {"slip_run": 0.0}, ""),
    "short tracks not voted on (only those seen once)": ("trackingworld", {"vote_short": 1}, ""),
    "the vote by 3D distance alone (no colour)": ("trackingworld", {"vote_colour_sigma": 0.0}, ""),
    "tracks seen once far from the voters: no fallback vote": ("trackingworld", {"vote_once_gap_px": float("inf")}, ""),
    "no photometric test of the dynamic tracks": ("trackingworld", {"photo_static_grey": 0.0}, ""),
    "photometric test in the hidden frames too (stop 46)": ("trackingworld", {"photo_static_hidden": False}, ""),
    "no occlusion test of the dynamic tracks": ("trackingworld", {"occluded_static_frames": 0}, ""),
    "every dynamic track solved in stage 3 (paper)": ("trackingworld", {"dynamic_cell": 0}, ""),
    "no reverse photometric test (--photo-moving 0)": ("trackingworld", {"photo_moving_share": 0.0}, ""),
    "no rigid-mover placement (--no-rigid-movers)": ("trackingworld", {"rigid_movers": False}, ""),
    "rigid groups not joined across gaps (--no-rigid-bridge)": ("trackingworld", {"rigid_bridge": False}, ""),
    "one search for rigid groups (--rigid-second-pass 0)": ("trackingworld", {"rigid_second_pass": 0}, ""),
    "rigid groups never cut in pieces (--rigid-split-gap 0)": ("trackingworld", {"rigid_split_gap": 0.0}, ""),
    "rigid groups never cut at a hand-off (--rigid-relay-gap 0)": ("trackingworld", {"rigid_relay_gap": 0.0}, ""),
    f"all {len(PAPER_LIKE)} as the paper": ("trackingworld", PAPER_LIKE, ""),
    "tracks: the upsampler's weighted mean (paper)": ("trackingworld", {}, "mean"),
    "tracks: no drag check in the flow tracker": ("trackingworld", {}, "nodrag"),
    "tracks: DIS's flow without the median (before stop 96)": ("trackingworld", {}, "dis"),
    f"all {len(PAPER_LIKE)} and the upsampler's mean as the paper": ("trackingworld", PAPER_LIKE, "mean"),
    "baseline (camera-centric)": ("baseline", {}, ""),
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--preset", default="default", choices=sorted(PRESETS))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="skip the Adam row (minutes)")
    ap.add_argument("--keep", action="store_true", help="keep the scratch folder of scenes, tracks and runs")
    ap.add_argument("--seeds", type=int, nargs="+", help="the full method and the baseline on these seeds' scenes")
    a = ap.parse_args(argv)
    work = scratch_dir("bench_optim_", a.keep)
    if a.seeds:
        return over_seeds(work, a.preset, a.seeds)
    scene = render_and_write(work / "scene", a.preset, a.seed)
    inp = scene / "input"
    frames, _ = read_frames(str(inp / "frames"))
    # every row runs on the default tracks but those naming a variant (TRACKS)
    tracks = {v: tracks_file(scene, work / f"tracks_{v or 'default'}.npz", **TRACKS[v]) for v in TRACKS}
    results = {}
    for name, (method, opts, variant) in ROWS.items():
        if a.quick and opts.get("solver") == "adam":
            continue
        r = run_and_evaluate(_config(method, inp, tracks[variant], **opts), work / f"run{len(results)}", scene, name)
        results[name] = {**r, "optim_s": sum(r["timings"].get(k, 0.0) for k in OPT_STAGES)}
    write(results, a.preset + (" --quick" if a.quick else ""), frames.shape)
    return 0


def _config(method: str, inp, tracks, **opts) -> RunConfig:
    """A run of ``method`` on a scene's given priors (``inp``: its input folder) and a tracks file."""
    return RunConfig(method=method, inputs=InputConfig(
        input=str(inp / "frames"), depth=str(inp / "depth.npy"), masks=str(inp / "masks"),
        intrinsics=str(inp / "intrinsics.txt")),
        track2d=Track2DConfig(tracker="file", tracks_file=str(tracks)), optim=OptimConfig(verbose=False, **opts))


def over_seeds(work, preset: str, seeds: list[int]) -> int:
    """The full method beside the baseline on one scene per seed (same tracks for both), and the full method on
    the tracks of the paper's upsampler (its weighted mean), with the means."""
    out = {}
    for sd in seeds:
        scene = render_and_write(work / f"scene{sd}", preset, sd)
        inp = scene / "input"
        tracks = tracks_file(scene, work / f"tracks{sd}.npz")
        mean_tracks = tracks_file(scene, work / f"tracks{sd}_mean.npz", **TRACKS["mean"])
        full = run_and_evaluate(_config("trackingworld", inp, tracks), work / f"full{sd}", scene, f"seed {sd} full")
        base = run_and_evaluate(_config("baseline", inp, tracks), work / f"base{sd}", scene, f"seed {sd} baseline")
        mean = run_and_evaluate(_config("trackingworld", inp, mean_tracks), work / f"mean{sd}", scene,
                                f"seed {sd} upsampler's mean")
        out[str(sd)] = {"full": {"metrics": full["metrics"], "timings": full["timings"]},
                        "baseline": {"metrics": base["metrics"]}, "upsampler_mean": {"metrics": mean["metrics"]}}
    write_seeds(out, preset)
    return 0


def write_seeds(out: dict, preset: str) -> None:
    """The table of :func:`over_seeds` from its per-seed metrics (``out``, also its json)."""
    seeds = list(out)
    head = ("| seed | ATE [% path] | track depth AbsRel (prior) | x prior | video depth AbsRel (prior) | "
            "world 3D acc all / dyn (centres' Sim(3): all) | static kept [%] | bg-mover recall [%] | "
            "optimisation [s] | baseline: ATE / track AbsRel / world | "
            "upsampler's mean: track AbsRel / world all / dyn |")
    lines = md_table_start(f"# World-centric optimiser over seeds of the `{preset}` preset",
                           f"Command: `.venv/bin/python benchmarks/bench_optim.py --preset {preset} --seeds "
                           f"{' '.join(seeds)}`", head)
    rows = []
    for sd in seeds:
        m, b, u = out[sd]["full"]["metrics"], out[sd]["baseline"]["metrics"], out[sd]["upsampler_mean"]["metrics"]
        opt_s = sum(out[sd]["full"]["timings"].get(k, 0.0) for k in OPT_STAGES)
        v = [m["camera"]["ate_pct_path"], m["track_depth"]["abs_rel_depth"], m["track_depth_prior"]["abs_rel_depth"],
             m["video_depth"]["abs_rel_depth"], m["video_depth_prior"]["abs_rel_depth"],
             m["world_3d"]["all"]["acc_avg"], m["world_3d"]["dynamic"]["acc_avg"],
             m["labels"]["static_kept_static"], m["labels"]["bg_mover_recall"],
             opt_s, b["camera"]["ate_pct_path"], b["track_depth"]["abs_rel_depth"], b["world_3d"]["all"]["acc_avg"],
             u["track_depth"]["abs_rel_depth"], u["world_3d"]["all"]["acc_avg"], u["world_3d"]["dynamic"]["acc_avg"],
             m.get("world_3d_centres", {"all": {}})["all"].get("acc_avg")]
        rows.append([np.nan if x is None else float(x) for x in v])
    for sd, r in zip([*seeds, "mean"], [*rows, list(np.nanmean(np.array(rows), 0))], strict=True):
        lines.append(f"| {sd} | {r[0]:.2f} | {r[1]:.4f} ({r[2]:.4f}) | {r[1] / r[2]:.2f} | {r[3]:.4f} ({r[4]:.4f}) | "
                     f"{r[5]:.1f} / {r[6]:.1f} ({r[16]:.1f}) | {r[7]:.1f} | {r[8]:.1f} | {r[9]:.1f} | "
                     f"{r[10]:.2f} / {r[11]:.4f} / {r[12]:.1f} | {r[13]:.4f} / {r[14]:.1f} / {r[15]:.1f} |")
    write_results(f"optim_{preset}_seeds", lines, out)


def write(results: dict, preset: str, shape) -> None:
    head = ("| configuration | ATE [% path] | RTE [m] | RRE [deg] | track depth AbsRel (prior) | "
            "video depth AbsRel (prior) | world 3D acc all / dyn | centres' Sim(3): all / dyn | static kept [%] | "
            "bg-mover recall [%] | optimisation [s] |")
    scene = preset.split()[0]
    lines = md_table_start(
        f"# World-centric optimiser on the `{scene}` scene ({shape[0]} frames, {shape[2]}x{shape[1]})",
        f"Command: `.venv/bin/python benchmarks/bench_optim.py --preset {preset}`", head)
    for name, r in results.items():
        m = r["metrics"]
        c, td, vd, w, lab = m["camera"], m["track_depth"], m["video_depth"], m["world_3d"], m["labels"]
        wc = m.get("world_3d_centres", {"all": {}, "dynamic": {}})
        lines.append(
            f"| {name} | {fmt(c['ate_pct_path'], 2)} | {fmt(c['rte'], 4)} | {fmt(c['rre'], 3)} | "
            f"{fmt(td['abs_rel_depth'], 4)} ({fmt(m['track_depth_prior']['abs_rel_depth'], 4)}) | "
            f"{fmt(vd['abs_rel_depth'], 4)} ({fmt(m['video_depth_prior']['abs_rel_depth'], 4)}) | "
            f"{fmt(w['all']['acc_avg'], 1)} / {fmt(w['dynamic']['acc_avg'], 1)} | "
            f"{fmt(wc['all'].get('acc_avg'), 1)} / {fmt(wc['dynamic'].get('acc_avg'), 1)} | "
            f"{fmt(lab['static_kept_static'], 1)} | {fmt(lab['bg_mover_recall'], 1)} | {r['optim_s']:.1f} |")
    write_results(f"optim_{scene}", lines, {k: {"metrics": v["metrics"], "timings": v["timings"], "wall_s": v["wall_s"]}
                                          for k, v in results.items()})


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
