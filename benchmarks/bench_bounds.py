"""What the scene allows (issue 4), run on demand: ``.venv/bin/python benchmarks/bench_bounds.py``.

Oracles on the ground truth of synthetic scenes, no tracker and no optimiser: the ground-truth static tracks
with the exact camera poses, lifted (a) by the depth prior frame by frame, (b) by the depth prior averaged over
each track's visible frames in the world frame, (c) by triangulation of their exact pixels plus Gaussian noise of
0.25 / 0.5 / 1 px. Reports world 3D accuracy (the metric of ``trackingworld eval``, no alignment needed: the
poses are exact) and depth Abs Rel against the prior's on the same observations. The gap between these and
the full method says how much is left to the tracker and the optimiser, and how much the scene's geometry and
its prior allow. Writes ``benchmarks/results/bounds.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from _common import md_table_start, write_results  # noqa: I001 (a sibling script module)
from trackingworld.eval.tracks import world_accuracy
from trackingworld.geometry import invert_pose, nearest_pixel, transform, unproject
from trackingworld.synth import render_and_write


def _rays_world(uv: np.ndarray, K: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    """Unit rays ``[n,3]`` in the world of pixels ``uv [n,2]`` seen from poses ``c2w [n,4,4]``."""
    d = np.einsum("nij,nj->ni", c2w[:, :3, :3], unproject(uv, np.ones(len(uv)), K))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def triangulate(uv: np.ndarray, K: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    """Least-squares intersection ``[3]`` of the rays of ``uv [n,2]`` from poses ``c2w [n,4,4]`` (midpoint
    method: minimises the sum of squared distances to the rays)."""
    d = _rays_world(uv, K, c2w)
    P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    return np.linalg.solve(P.sum(0), np.einsum("nij,nj->i", P, c2w[:, :3, 3]))


def bounds(scene: Path, noise_px=(0.25, 0.5, 1.0), seed: int = 0) -> dict:
    g = np.load(scene / "gt.npz")
    prior = np.load(scene / "input" / "depth.npy")
    K, c2w = g["K"].astype(np.float64), g["poses_c2w"].astype(np.float64)
    T, H, W = prior.shape
    static = ~(g["tracks_dynamic"] | g["tracks_bg_mover"]) & (g["tracks_vis"].sum(1) >= 2)
    idx = np.flatnonzero(static)
    uv, vis, gt_xyz = g["tracks_uv"].astype(np.float64), g["tracks_vis"], g["tracks_xyz"]
    w2c = invert_pose(c2w)
    rng = np.random.default_rng(seed)
    est = {"prior per frame": np.zeros((len(idx), T, 3)), "prior averaged in the world": np.zeros((len(idx), T, 3))}
    est |= {f"triangulation, {s} px noise": np.zeros((len(idx), T, 3)) for s in noise_px}
    z_obs, z_gt, z_est = [], [], {k: [] for k in est}
    for n, i in enumerate(idx):
        ts = np.flatnonzero(vis[i])
        x, y = nearest_pixel(uv[i, ts], W, H)
        z = prior[ts, y, x].astype(np.float64)
        pw = transform(c2w[ts], unproject(uv[i, ts], z, K))
        est["prior per frame"][n, ts] = pw
        est["prior averaged in the world"][n] = pw.mean(0)
        for s in noise_px:
            est[f"triangulation, {s} px noise"][n] = triangulate(uv[i, ts] + s * rng.standard_normal((len(ts), 2)),
                                                                K, c2w[ts])
        z_obs.append(z)
        z_gt.append(g["depth"][ts, y, x].astype(np.float64))
        for k, e in est.items():
            z_est[k].append(transform(w2c[ts], e[n, ts])[:, 2])
    zg, zp = np.concatenate(z_gt), np.concatenate(z_obs)
    prior_absrel = float(np.mean(np.abs(zp - zg) / zg))
    rows = {}
    for k, e in est.items():
        acc = world_accuracy(e, gt_xyz[idx], vis[idx], g["query_frame"][idx])
        ze = np.concatenate(z_est[k])
        rows[k] = {"world_acc": acc["acc_avg"], "abs_rel": float(np.mean(np.abs(ze - zg) / zg)),
                   "prior_abs_rel": prior_absrel}
    return {"tracks": int(len(idx)), "median_depth_m": float(np.median(g["depth"])), "f_px": float(K[0, 0]),
            "rows": rows}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--scenes", default="default:0,default:1,default:2,default:3,hard:0",
                    help="PRESET:SEED,... of the synthetic scenes")
    a = ap.parse_args(argv)
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for spec in a.scenes.split(","):
            preset, seed = spec.split(":")
            scene = render_and_write(Path(tmp) / spec.replace(":", "_"), preset, int(seed), verbose=False)
            results[spec] = bounds(scene)
            print(spec, results[spec], file=sys.stderr, flush=True)
    names = list(next(iter(results.values()))["rows"])
    head = "| scene | " + " | ".join(f"{n}: world acc / AbsRel" for n in names) + " | prior AbsRel |"
    lines = md_table_start("# Oracle bounds: ground-truth static tracks and exact poses",
                           f"Command: `.venv/bin/python benchmarks/bench_bounds.py --scenes {a.scenes}`", head)
    for spec, r in results.items():
        cells = [f"{r['rows'][n]['world_acc']:.1f} / {r['rows'][n]['abs_rel']:.4f}" for n in names]
        lines.append(f"| {spec} | " + " | ".join(cells) + f" | {r['rows'][names[0]]['prior_abs_rel']:.4f} |")
    write_results("bounds", lines, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
