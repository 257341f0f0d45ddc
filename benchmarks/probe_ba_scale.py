"""How long the bundle adjustment makes the camera path against the truth's, with the scene's own inputs and with
ever more of them exact: the true depth as the prior, masks from the true movers, then true static tracks with
Gaussian noise of each given size, drawn with each of ``--seeds`` seeds. The path's scale against the prior's
depths is stage 2's weakest mode: with true tracks, depth and masks, 0.3 px of noise moves it by -0.06% to +0.48%
from one draw to the next (stop 82), and after the Sim(3) the points whose depth only the prior sets are off by
about as much.

    .venv/bin/python benchmarks/probe_ba_scale.py bench_out/scenes/default50 --noise 0.3 --seeds 3

Each row is one ``trackingworld run`` on the scene's frames (its cached ``tracks.npz`` for the first three rows),
evaluated against its ground truth. Writes ``benchmarks/results/probe_ba_scale_<scene>.md`` (and prints it).
The true tracks start on every ``--grid`` px of every ``--every``-th frame on the static background and are seen
where the true depth at their projection agrees with theirs within 2%; their query frame is kept exact.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from _common import run_and_evaluate, scratch_dir, write_results  # noqa: I001 (a sibling script module)
from trackingworld.config import InputConfig, RunConfig, Track2DConfig
from trackingworld.eval.dense import static_points
from trackingworld.eval.evaluate import load_gt
from trackingworld.geometry import invert_pose, project, transform
from trackingworld.io.atomic import write_npz
from trackingworld.io.result import load_result

VISIBLE_DEPTH_TOL = 0.02  # a true track is seen where the true depth at its projection is within this of its own
MASK_DILATE_PX = 3


def true_static_tracks(gt: dict, grid: int, every: int, noise: float, rng: np.random.Generator):
    """Static tracks from the ground truth: ``(uv [N,T,2] px, vis [N,T], queries [N,3] (frame, x, y))``, started on
    every ``grid`` px of every ``every``-th frame where no true mover is, their true points
    (``eval.dense.static_points``) projected with the true poses into every frame, seen there while inside the image,
    off every mover and at the true depth within VISIBLE_DEPTH_TOL; uv with Gaussian noise of ``noise`` px off the
    query frame, which keeps the query pixel itself."""
    depth, moving, K, P = gt["depth"], gt["dynamic"], gt["K"].astype(np.float64), gt["poses_c2w"]
    T, H, W = depth.shape
    ys, xs = (a.ravel() for a in np.mgrid[grid // 2:H:grid, grid // 2:W:grid])
    qs = []
    for q in range(0, T, every):
        keep = ~moving[q, ys, xs]
        qs.append(np.stack([np.full(int(keep.sum()), q), xs[keep], ys[keep]], 1))
    queries = np.concatenate(qs)
    qf, px = queries[:, 0], queries[:, 1:].astype(np.float64)
    n = np.arange(len(queries))
    uv = np.zeros((len(queries), T, 2))
    uv[n, qf] = px
    world, _ = static_points(uv, qf, depth, P, K)
    # the noise drawn query frame by query frame, then frame by frame, none at the query frame
    draws = np.zeros((len(queries), T, 2))
    at = 0
    for block in qs:
        q = int(block[0, 0]) if len(block) else 0
        for t in range(T):
            if t != q:
                draws[at:at + len(block), t] = rng.standard_normal((len(block), 2))
        at += len(block)
    vis = np.zeros((len(queries), T), bool)
    w2c = invert_pose(P)
    for t in range(T):
        u, z = project(transform(w2c[t], world), K)
        xi = np.clip(np.round(u[:, 0]).astype(int), 0, W - 1)
        yi = np.clip(np.round(u[:, 1]).astype(int), 0, H - 1)
        inside = (u[:, 0] >= 0) & (u[:, 0] <= W - 1) & (u[:, 1] >= 0) & (u[:, 1] <= H - 1) & (z > 0)
        agree = np.abs(z / np.maximum(depth[t, yi, xi], 1e-6) - 1) < VISIBLE_DEPTH_TOL
        vis[:, t] = inside & agree & ~moving[t, yi, xi]
        uv[:, t] = u + noise * draws[:, t]
    uv[n, qf] = px  # the query pixel itself
    vis[n, qf] = True
    return uv, vis, queries.astype(np.float32)


def path_ratio(poses: np.ndarray, truth: np.ndarray) -> float:
    """The length of a camera path ``[T,4,4]`` (camera-to-world) over that of the true one."""
    def length(p):
        return float(np.linalg.norm(np.diff(p[:, :3, 3].astype(np.float64), axis=0), axis=1).sum())
    return length(poses) / length(truth)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", type=Path, help="a synthetic scene folder with its tracks.npz (bench_scenes.py's cache)")
    ap.add_argument("--noise", type=float, nargs="+", default=[0.3], help="px of noise on the true tracks")
    ap.add_argument("--seeds", type=int, default=3, help="draws of the noise at each size (seeds 0, 1, ...)")
    ap.add_argument("--grid", type=int, default=4)
    ap.add_argument("--every", type=int, default=4)
    ap.add_argument("--keep", action="store_true", help="keep the scratch folder of inputs and runs")
    a = ap.parse_args(argv)
    inp = a.scene / "input"
    if not (a.scene / "gt.npz").is_file() or not (a.scene / "tracks.npz").is_file():
        raise SystemExit(f"probe_ba_scale: {a.scene}: needs gt.npz and tracks.npz (a bench_scenes.py cache folder)")
    gt = load_gt(a.scene, np.load(inp / "depth.npy", mmap_mode="r").shape[0])
    work = scratch_dir("probe_ba_scale_", a.keep)
    np.save(work / "true_depth.npy", gt["depth"].astype(np.float32))
    (work / "true_masks").mkdir()
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * MASK_DILATE_PX + 1,) * 2)
    for t, f in enumerate(sorted((inp / "masks").iterdir())):
        cv2.imwrite(str(work / "true_masks" / f.name), cv2.dilate(gt["dynamic"][t].astype(np.uint8), kernel) * 255)
    rows = [("the scene's own inputs", a.scene / "tracks.npz", inp / "depth.npy", inp / "masks"),
            ("the true depth as the prior", a.scene / "tracks.npz", work / "true_depth.npy", inp / "masks"),
            ("... and the true movers' masks", a.scene / "tracks.npz", work / "true_depth.npy", work / "true_masks")]
    for s in a.noise:
        for seed in range(a.seeds):
            uv, vis, q = true_static_tracks(gt, a.grid, a.every, s, np.random.default_rng(seed))
            path = work / f"true_tracks_{s:g}_{seed}.npz"
            write_npz(path, tracks=uv.transpose(1, 0, 2).astype(np.float32), visibility=vis.T, queries=q)
            rows.append((f"true static tracks ({len(q):,}), {s:g} px of noise (seed {seed}), true depth and masks",
                         path, work / "true_depth.npy", work / "true_masks"))
    lines = [f"# The camera path's length against the truth's: `{a.scene.name}`", "",
             f"Command: `.venv/bin/python benchmarks/probe_ba_scale.py {a.scene} --noise "
             f"{' '.join(f'{s:g}' for s in a.noise)} --seeds {a.seeds}`", "",
             "The true tracks lie on the static background only: on their rows, the world 3D accuracy of all and of "
             "the dynamic queries scores tracks that are not there.", "",
             "| inputs | path / true path | world 3D accuracy: all / static / dynamic |", "|---|---|---|"]
    data = []
    for i, (name, tracks, depth, masks) in enumerate(rows):
        given = InputConfig(input=str(inp / "frames"), depth=str(depth), masks=str(masks),
                            intrinsics=str(inp / "intrinsics.txt"))
        cfg = RunConfig(inputs=given, track2d=Track2DConfig(tracker="file", tracks_file=str(tracks)))
        r = run_and_evaluate(cfg, work / f"run{i}", a.scene, name)
        ratio = path_ratio(load_result(work / f"run{i}").poses_c2w, gt["poses_c2w"])
        w = r["metrics"]["world_3d"]
        acc = [(w.get(k) or {}).get("acc_avg") for k in ("all", "static", "dynamic")]
        acc = [float("nan") if x is None else x for x in acc]  # no dynamic query: none scored
        lines.append(f"| {name} | {ratio:.4f} | {' / '.join(f'{x:.2f}' for x in acc)} |")
        data.append({"inputs": name, "path_ratio": ratio, "world_3d": acc})
    write_results(f"probe_ba_scale_{a.scene.name}", lines, {"rows": data})
    return 0


if __name__ == "__main__":
    sys.exit(main())
