"""The pipeline on a CUDA device agrees with the CPU run. Skipped where torch sees no CUDA device (CI, the 2-core
development machine); run on a GPU machine with ``pytest tests/test_cuda.py``."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from trackingworld.cli.main import main
from trackingworld.geometry import intrinsics_matrix, invert_pose, pose_from_rt, project, transform
from trackingworld.optim import stage3

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")


def _run(scene, out, device, *extra):
    inp = scene / "input"
    assert main(["run", str(inp / "frames"), "--out", str(out), "--depth", str(inp / "depth.npy"),
                 "--masks", str(inp / "masks"), "--intrinsics", str(inp / "intrinsics.txt"), "--quiet",
                 "--device", device, *extra]) == 0
    assert main(["eval", str(out), "--gt", str(scene)]) == 0
    return json.loads((out / "metrics.json").read_text()), np.load(out / "result.npz")


def test_full_run_on_cuda_matches_the_cpu_run(tiny_scene, tmp_path):
    """2D tracks, stages 1-3 and video depth on the GPU: the same result contract and the same accuracy as on
    the CPU (float32 on another device and stage 3's CG instead of AMG: close, not bit-equal)."""
    m_cpu, r_cpu = _run(tiny_scene, tmp_path / "cpu", "cpu")
    m_gpu, r_gpu = _run(tiny_scene, tmp_path / "cuda", "cuda")
    assert json.loads((tmp_path / "cuda" / "config.json").read_text())["device"] == "cuda"
    assert set(r_cpu.files) == set(r_gpu.files)
    for k in r_cpu.files:
        assert r_cpu[k].shape[1:] == r_gpu[k].shape[1:] and r_cpu[k].dtype == r_gpu[k].dtype, k
    # the dense tracker on another device: (nearly) the same tracks, the first frame's queries in the same order
    n_cpu, n_gpu = len(r_cpu["query_frame"]), len(r_gpu["query_frame"])
    assert abs(n_gpu - n_cpu) <= 0.01 * n_cpu
    n0 = int((r_cpu["query_frame"] == 0).sum())
    assert int((r_gpu["query_frame"] == 0).sum()) == n0
    both = r_cpu["visible"][:n0] & r_gpu["visible"][:n0]
    assert both.mean() > 0.5 and np.median(np.abs(r_gpu["tracks_2d"][:n0] - r_cpu["tracks_2d"][:n0])[both]) < 0.05
    np.testing.assert_allclose(r_gpu["poses_c2w"][:, :3, 3], r_cpu["poses_c2w"][:, :3, 3], atol=0.02)
    assert abs(m_gpu["camera"]["ate_pct_path"] - m_cpu["camera"]["ate_pct_path"]) < 0.5
    assert abs(m_gpu["world_3d"]["all"]["acc_avg"] - m_cpu["world_3d"]["all"]["acc_avg"]) < 3.0
    assert m_gpu["track_depth"]["abs_rel_depth"] < 1.2 * m_cpu["track_depth"]["abs_rel_depth"] + 1e-3
    assert m_gpu["video_depth"]["abs_rel_depth"] < 1.2 * m_cpu["video_depth"]["abs_rel_depth"] + 1e-3


def test_adam_reference_runs_on_cuda(tiny_scene, tmp_path):
    m, _ = _run(tiny_scene, tmp_path / "adam", "cuda", "--solver", "adam", "--max-frames", "6")
    assert json.loads((tmp_path / "adam" / "config.json").read_text())["device"] == "cuda"
    assert np.isfinite(m["camera"]["ate"])


def test_stage3_cg_on_cuda_reaches_the_cpu_amg_solution():
    """The stage-3 sparse problem: conjugate gradients on the GPU and algebraic multigrid on the CPU agree."""
    rng = np.random.default_rng(0)
    T, N = 8, 200
    K = intrinsics_matrix(300.0, 300.0, 64.0, 48.0)
    c2w = np.stack([pose_from_rt(np.eye(3), np.array([0.05 * t, 0, 0])) for t in range(T)])
    X = np.stack([rng.uniform(-0.3, 0.3, N), rng.uniform(-0.3, 0.3, N), rng.uniform(3.8, 4.2, N)], 1)
    Xt = X[None] + np.arange(T)[:, None, None] * np.array([0.02, 0, -0.08])  # one rigid mover
    uv, z = project(transform(invert_pose(c2w)[:, None], Xt), K)
    uv, z = uv.transpose(1, 0, 2), z.T
    vis = rng.random((N, T)) > 0.2
    noisy = z * (1 + 0.03 * rng.standard_normal(z.shape))
    nb = stage3.neighbours(Xt.transpose(1, 0, 2), vis, np.zeros(N, np.int64), 4)
    sols = {}
    for dev in ("cpu", "cuda"):
        p = stage3.build_problem(uv, vis, noisy, c2w, K, nb, (1.0, 1.0, 100.0, 10.0), torch.float64, dev)
        d0 = p.target.clone()
        d = stage3.solve_amg(p, d0, tol=1e-10) if dev == "cpu" else stage3.solve_cg(p, d0, iters=3000, tol=1e-14)
        assert d.device.type == dev
        sols[dev] = d.cpu()
    assert torch.allclose(sols["cuda"], sols["cpu"], atol=1e-5)
    assert (sols["cuda"] - torch.as_tensor(z[vis])).abs().mean() < (torch.as_tensor(noisy[vis] - z[vis])).abs().mean()


def test_rigid_movers_on_cuda_find_the_cpu_groups_and_positions():
    """The rigid-mover step (stage 2's solver on the run's device, float64 as the pipeline runs it): the same
    groups and, to a tenth of a millimetre, the same positions as on the CPU."""
    from test_rigid import T, _lift, _scene
    from trackingworld.config import OptimConfig
    from trackingworld.optim.rigid import RigidSettings, rigid_movers

    uv, vis, X, z, poses, K, qf = _scene(rigid=True)
    target = z * (1 + 0.1 * np.sin(np.arange(T) / T * 2 * np.pi)[None])
    start = _lift(uv, target, poses, K)
    res = {dev: rigid_movers(uv, vis, target, start, poses, K, qf, OptimConfig(), RigidSettings(), device=dev)
           for dev in ("cpu", "cuda")}
    assert res["cpu"][3]["rigid_groups"] >= 1 and res["cuda"][3] == res["cpu"][3]
    np.testing.assert_array_equal(res["cuda"][1], res["cpu"][1])
    np.testing.assert_allclose(res["cuda"][0], res["cpu"][0], atol=1e-4)
