"""optim.point_fit, optim.ba_blocks, optim.static_fit: the compiled CPU kernels give the torch reference's numbers."""

from dataclasses import replace

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from trackingworld.config import OptimConfig
from trackingworld.geometry import intrinsics_matrix
from trackingworld.optim import (
    ba_blocks,
    densify,
    parallel,
    photo_static,
    point_fit,
    ratio_field,
    rigid,
    stage2,
    static_fit,
)
from trackingworld.optim.point_fit import fit_and_score
from trackingworld.optim.static_tests import fits_static


def _problem(seed: int = 0, n: int = 300, T: int = 12):
    """Tracks of points seen by T cameras (camera-from-object R, t), with pixel noise, a biased and noisy depth
    target, a third of them off the motion (outliers), and some seen in 0, 1 or 2 frames."""
    rng = np.random.default_rng(seed)
    K = intrinsics_matrix(300.0, 290.0, 160.0, 120.0)
    R = Rotation.from_rotvec(rng.normal(0, 0.1, (T, 3))).as_matrix()
    t = np.c_[rng.normal(0, 0.2, (T, 2)), 3 + rng.normal(0, 0.2, T)]
    X = rng.uniform(-0.5, 0.5, (n, 3))
    Y = np.einsum("tij,nj->nti", R, X) + t[None]
    Y[: n // 3] += rng.normal(0, 0.05, (n // 3, T, 3))  # not on the motion
    uv = np.stack([K[0, 0] * Y[..., 0] / Y[..., 2] + K[0, 2], K[1, 1] * Y[..., 1] / Y[..., 2] + K[1, 2]], -1)
    uv += rng.normal(0, 0.3, uv.shape)
    target = Y[..., 2] * 1.03 * np.exp(rng.normal(0, 0.02, Y.shape[:2]))
    vis = rng.random((n, T)) < 0.8
    vis[-3:] = False
    vis[-3, 0] = vis[-2, :2] = True  # seen in 1 and 2 frames (no quantiles), the last in none
    return uv, vis, target, K, R, t


@pytest.mark.parametrize("offsets,space", [(True, "log"), (True, "metres"), (False, "log")])
def test_the_compiled_fit_gives_the_torch_reference(offsets, space):
    uv, vis, target, K, R, t = _problem()
    T = vis.shape[1]
    frames = np.array([3, 0, 5, 7, 1, 2, 4, 6, 8, 9, 11])  # a motion solved in all frames but one, its own order
    motion = (frames, torch.as_tensor(R[frames]), torch.as_tensor(t[frames]))
    cfg = replace(OptimConfig(), no_offsets=not offsets, dc_space=space, lambda_asap=4.0)
    rows = np.r_[np.arange(0, len(vis), 2), len(vis) - 3, len(vis) - 2, len(vis) - 1]
    P, q, dz = rigid.place_on_motion(uv, vis, target, motion, K, cfg, rows=rows)
    Pr, qr, dzr = rigid._place_on_motion_torch(uv[rows], vis[rows], target[rows], motion, K, cfg)
    assert T == 12 and len(P) == len(rows)
    np.testing.assert_allclose(P, Pr, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(np.isinf(q), np.isinf(qr))
    np.testing.assert_allclose(q[np.isfinite(q)], qr[np.isfinite(qr)], rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(np.isnan(dz), np.isnan(dzr))
    np.testing.assert_allclose(dz[~np.isnan(dz)], dzr[~np.isnan(dzr)], rtol=1e-9, atol=1e-12)
    # the test itself separates the tracks on the motion from those off it
    ok = (q[:, 0] <= 0.6) & (q[:, 1] <= 1.5)
    on = np.arange(len(vis))[rows] >= len(vis) // 3
    assert ok[on].mean() > 0.5 and ok[~on].mean() < 0.1
    assert np.isinf(q[-3:]).all() and np.isnan(dz[-1]) and np.isfinite(dz[-3:-1]).all()


def test_no_steps_leave_the_mean_back_projection():
    uv, vis, target, K, R, t = _problem(seed=1, n=40)
    P, _, _ = fit_and_score(R, t, K, uv, target, vis, (1.0, 1.0, 5.0), iters=0)
    i = 5
    f = np.flatnonzero(vis[i])
    ray = np.c_[(uv[i, f, 0] - K[0, 2]) / K[0, 0], (uv[i, f, 1] - K[1, 2]) / K[1, 1], np.ones(len(f))]
    c = ray * target[i, f, None]
    X = np.einsum("fji,fj->fi", R[f], c - t[f])  # R^T (c - t)
    np.testing.assert_allclose(P[i], X.mean(0), atol=1e-12)


@pytest.mark.parametrize("offsets,space,weighted", [(True, "log", False), (True, "metres", True), (False, "log", True)])
def test_the_compiled_blocks_give_the_torch_reference(offsets, space, weighted):
    uv, vis, target, K, R, t = _problem(seed=2, n=200)
    cfg = replace(OptimConfig(), no_offsets=not offsets, dc_space=space)
    p = stage2.BAProblem.from_tracks(uv, target, vis, K, cfg, torch.float64, "cpu")
    if weighted:
        p = replace(p, dc_weight=torch.rand(len(p.pt), dtype=torch.float64, generator=torch.Generator().manual_seed(0)))
    Rt, tt = torch.as_tensor(R), torch.as_tensor(t)
    X = stage2.init_points(Rt, tt, p) + 0.01  # off the optimum: the kernels' weights below 1 somewhere
    ref = stage2._linearize(Rt, tt, X, p, focal=True)[:5]  # the focal unknown keeps the torch path
    got = stage2._linearize(Rt, tt, X, p)
    for a, b in zip(got, ref, strict=True):
        scale = b.abs().max()
        torch.testing.assert_close(a, b, rtol=0, atol=1e-12 * float(scale))
    _, Hxx, _, _, gx = stage2._linearize(Rt, tt, X, p, points_only=True)
    torch.testing.assert_close(Hxx, ref[1], rtol=0, atol=1e-12 * float(ref[1].abs().max()))
    torch.testing.assert_close(gx, ref[4], rtol=0, atol=1e-12 * float(ref[4].abs().max()))
    # the Huber weights matter (offsets on) or are all 1 (off)
    plain = stage2._linearize(Rt, tt, X, replace(p, offsets=False))[1]
    assert offsets == bool((got[1] != plain).any())
    # and the objective's value: as given, at a refined focal length (its kernel at the starting one), without the
    # depth term
    for q in (p, p.with_focal_scale(0.05), replace(p, lambda_dc=0.0)):
        ref_cost = float(stage2.loss(Rt, tt, X, q))
        assert abs(stage2.loss_value(Rt, tt, X, q) - ref_cost) <= 1e-12 * ref_cost
    assert stage2.loss_value(Rt, tt, X, p) != stage2.loss_value(Rt, tt, X, p.with_focal_scale(0.05))


def test_the_compiled_step_gives_the_torch_reference(monkeypatch):
    uv, vis, target, K, R, t = _problem(seed=3, n=150)
    p = stage2.BAProblem.from_tracks(uv, target, vis, K, OptimConfig(), torch.float64, "cpu")
    Rt, tt = torch.as_tensor(R), torch.as_tensor(t)
    X = stage2.init_points(Rt, tt, p)
    blocks = stage2._linearize(Rt, tt, X, p)
    free = torch.ones(p.n_frames, dtype=torch.bool)
    free[0] = False
    dc, dx, _ = stage2._schur_step(*blocks, p, 1e-3, free)
    monkeypatch.setattr(stage2.ba_blocks, "schur_step", lambda *a: None)  # the eigen-decomposition and torch
    dc_ref, dx_ref, _ = stage2._schur_step(*blocks, p, 1e-3, free)
    assert float(dc_ref.abs().max()) > 1e-4 and (dc[0] == 0).all()  # a real step; frame 0 stays fixed
    torch.testing.assert_close(dc, dc_ref, rtol=0, atol=1e-10 * float(dc_ref.abs().max()))
    torch.testing.assert_close(dx, dx_ref, rtol=0, atol=1e-10 * float(dx_ref.abs().max()))
    # and a whole solve reaches the same poses and cost
    ref = stage2.solve_lm(Rt, tt, X, p, iters=10)
    monkeypatch.undo()
    sol = stage2.solve_lm(Rt, tt, X, p, iters=10)
    assert abs(sol.cost - ref.cost) <= 1e-9 * ref.cost
    torch.testing.assert_close(sol.t, ref.t, rtol=0, atol=1e-9)



def _windowed(vis: np.ndarray, seed: int) -> np.ndarray:
    """``vis`` kept in a window of 3-8 frames per track, as a long video's static points are seen."""
    rng = np.random.default_rng(seed)
    n, T = vis.shape
    out = np.zeros_like(vis)
    for i in range(n):
        s = rng.integers(0, T - 8)
        out[i, s:s + rng.integers(3, 9)] = True
    return out & (vis | (rng.random(vis.shape) < 0.5))


@pytest.mark.parametrize("how", ["blas", "pairs"])
@pytest.mark.parametrize("windowed", [False, True])
def test_both_ways_of_forming_the_reduced_system_give_the_torch_step(how, windowed, monkeypatch):
    uv, vis, target, K, R, t = _problem(seed=6, n=300, T=30)
    if windowed:
        vis = _windowed(vis, 0)
    p = stage2.BAProblem.from_tracks(uv, target, vis, K, OptimConfig(), torch.float64, "cpu")
    Rt, tt = torch.as_tensor(R), torch.as_tensor(t)
    blocks = stage2._linearize(Rt, tt, stage2.init_points(Rt, tt, p), p)
    free = torch.ones(p.n_frames, dtype=torch.bool)
    free[0] = False
    dc, dx = ba_blocks.schur_step(*(b.numpy() for b in blocks), p.pt.numpy(), p.fr.numpy(), 1e-3, free.numpy(), how)
    monkeypatch.setattr(stage2.ba_blocks, "schur_step", lambda *a: None)  # torch
    dc_ref, dx_ref, _ = stage2._schur_step(*blocks, p, 1e-3, free)
    assert float(dc_ref.abs().max()) > 1e-4 and (dc[0] == 0).all()
    np.testing.assert_allclose(dc, dc_ref.numpy(), rtol=0, atol=1e-10 * float(dc_ref.abs().max()))
    np.testing.assert_allclose(dx, dx_ref.numpy(), rtol=0, atol=1e-10 * float(dx_ref.abs().max()))
    # the cheaper way is the one taken: the product of the dense coupling where each point is seen in most frames,
    # the pairs where in a few
    chosen, cost = ba_blocks.reduced_cost(p.pt.numpy(), p.n_points, p.n_frames)
    assert chosen == ("pairs" if windowed else "blas") and cost > 0
    monkeypatch.undo()
    taken = []
    step = ba_blocks.schur_step
    monkeypatch.setattr(stage2.ba_blocks, "schur_step", lambda *a: taken.append(a[-1]) or step(*a))
    stage2._schur_step(*blocks, p, 1e-3, free)
    assert taken == [chosen]


def test_a_block_cholesky_refuses_is_factored_by_its_eigen_decomposition():
    # the Schur step's fallback for a point block that is not positive definite in floating point: its inverse from
    # the eigen-decomposition, as the torch step does for every block
    H = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]])
    out = np.zeros((3, 3))
    assert ba_blocks._chol3(H, out) and not ba_blocks._chol3(np.diag([1.0, 1.0, -1e-18]), out)
    lam, V = np.linalg.eigh(H)
    b, x = np.array([0.3, -1.0, 2.0]), np.zeros(3)
    ba_blocks._apply(V / np.sqrt(lam), 1, b, x)
    np.testing.assert_allclose(x, np.linalg.solve(H, b), rtol=1e-12)
    ba_blocks._apply(np.linalg.cholesky(H), 0, b, x)
    np.testing.assert_allclose(x, np.linalg.solve(H, b), rtol=1e-12)


def test_the_switch_runs_the_torch_code_everywhere(monkeypatch):
    uv, vis, target, K, R, t = _problem(seed=5, n=40)
    frames = np.arange(vis.shape[1])
    motion = (frames, torch.as_tensor(R), torch.as_tensor(t))
    monkeypatch.setattr(stage2, "COMPILED", False)
    got = rigid.place_on_motion(uv, vis, target, motion, K, OptimConfig(), rows=np.arange(10))
    ref = rigid._place_on_motion_torch(uv[:10], vis[:10], target[:10], motion, K, OptimConfig())
    for a, b in zip(got, ref, strict=True):
        np.testing.assert_array_equal(a, b)
    assert not stage2.compiled(torch.as_tensor(R))


def test_the_warm_up_compiles_every_kernel_the_pipeline_calls():
    from trackingworld.optim import point_fit, warmup

    assert warmup.warm() > 0
    kernels = (point_fit._fit_and_score, ba_blocks._blocks, ba_blocks._cost, ba_blocks._reduce, ba_blocks._coupling,
               ba_blocks._subtract_pairs, ba_blocks._back, static_fit._fit_points, densify._idw,
               photo_static._project_and_test_kernel, densify._thin_kernel, ratio_field._normal_blocks,
               ratio_field._reweight, ratio_field._field_at)
    assert all(k.signatures for k in kernels)


def _static_problem(seed: int, n: int, T: int, cfg: OptimConfig, dc_weight: bool = False):
    """A float32 problem of the static tests (poses world-to-camera, observations by point) from :func:`_problem`,
    with per-observation depth weights where asked."""
    uv, vis, target, K, R, t = _problem(seed=seed, n=n, T=T)
    p = stage2.BAProblem.from_tracks(uv, target, vis, K, cfg, torch.float32, "cpu")
    if dc_weight:
        p = replace(p, dc_weight=torch.rand(len(p.pt), generator=torch.Generator().manual_seed(seed)) + 0.5)
    return p, torch.as_tensor(R, dtype=torch.float32), torch.as_tensor(t, dtype=torch.float32)


@pytest.mark.parametrize("offsets,space,weighted,focal", [(True, "log", False, None), (True, "metres", False, None),
                                                          (False, "log", False, None), (True, "log", True, 310.0)])
def test_the_compiled_static_fit_gives_the_torch_float32_points(offsets, space, weighted, focal, monkeypatch):
    cfg = replace(OptimConfig(), no_offsets=not offsets, dc_space=space)
    p, R, t = _static_problem(3, 2000, 20, cfg, weighted)
    p = replace(p, kernel_focal=focal)
    got = stage2.fit_points(R, t, p)
    monkeypatch.setattr(stage2, "COMPILED", False)
    ref = stage2.fit_points(R, t, p)
    monkeypatch.undo()
    X64 = stage2.fit_points(R.double(), t.double(), replace(
        p, uv=p.uv.double(), depth=p.depth.double(), K=p.K.double(),
        dc_weight=None if p.dc_weight is None else p.dc_weight.double()))
    assert got.dtype == torch.float32 and got.shape == ref.shape == (p.n_points, 3)
    seen = torch.bincount(p.pt, minlength=p.n_points) > 0
    assert (got[~seen] == 0).all() and (ref[~seen] == 0).all()  # a track seen nowhere: the origin, as torch's
    # within float32's rounding of the torch reference, which is as far from float64's numbers as the kernel is
    diff = (got - ref).abs().max().item()
    assert diff <= 2e-6
    assert (got.double() - X64).abs().max().item() <= 2 * (ref.double() - X64).abs().max().item() + 1e-7
    # ... and most points to the last bit
    assert (got == ref).all(1).float().mean().item() > 0.4


def test_the_compiled_static_fit_reads_observations_in_any_order():
    p, R, t = _static_problem(4, 300, 10, OptimConfig())
    perm = torch.randperm(len(p.pt), generator=torch.Generator().manual_seed(0))
    shuffled = replace(p, pt=p.pt[perm], fr=p.fr[perm], uv=p.uv[perm], depth=p.depth[perm])
    np.testing.assert_allclose(stage2.fit_points(R, t, shuffled), stage2.fit_points(R, t, p), rtol=0, atol=2e-6)


def test_the_static_tests_take_the_same_verdicts_as_the_torch_reference(monkeypatch):
    uv, vis, target, K, R, t = _problem(seed=6, n=3000, T=16)
    Rt, tt = torch.as_tensor(R), torch.as_tensor(t)
    cfg = replace(OptimConfig(), epsilon=0.02)
    got = fits_static(uv, target, vis, K, Rt, tt, cfg, torch.float32, "cpu")
    monkeypatch.setattr(stage2, "COMPILED", False)
    ref = fits_static(uv, target, vis, K, Rt, tt, cfg, torch.float32, "cpu")
    assert 0.2 < got[0].mean() < 0.9  # the third off the motion fails, as do some with the noisy target
    assert (got[0] != ref[0]).sum() <= 3
    np.testing.assert_allclose(got[1], ref[1], rtol=0, atol=2e-6)


def test_parts_cover_the_items_once_at_equal_cost_and_small_work_stays_whole():
    cost = np.r_[0, np.cumsum(np.r_[np.ones(90), np.full(10, 9.0)])]  # the last tenth of the items costs half
    b = parallel.part_bounds(cost, 2, 1.0)
    assert b.tolist() == [0, 90, 100]
    assert parallel.part_bounds(cost, 4, 1000.0).tolist() == [0, 100]  # cheaper than a part: one
    assert parallel.part_bounds(np.zeros(1), 4, 1.0).tolist() == [0, 0]  # no items: one empty part
    b = parallel.part_bounds(np.arange(8), 16, 1.0)  # more threads than items: one item a part at most
    assert b[0] == 0 and b[-1] == 7 and np.all(np.diff(b) >= 1)
    seen = parallel.in_parts(lambda lo, hi: list(range(lo, hi)), parallel.part_bounds(np.arange(1001), 3, 1.0))
    assert sum(seen, []) == list(range(1000)) and len(seen) == 3


def test_the_kernels_split_among_threads_give_the_same_numbers_to_the_bit(monkeypatch):
    """The track fits, the static fits and the fields' normal equations in parts on threads against one part."""
    uv, vis, target, K, R, t = _problem(seed=8, n=3000, T=12)
    rows = np.arange(0, 3000, 2)
    p, Rs, ts = _static_problem(9, 3000, 12, OptimConfig())
    rng = np.random.default_rng(1)
    samples = [(rng.uniform([0, 0], [319, 239], (n, 2)), rng.normal(0, 0.05, n)) for n in (900, 0, 2500, 40)]
    samples[1] = None

    def run():
        return (fit_and_score(R, t, K, uv, target, vis, (1.0, 1.0, 5.0), rows=rows), stage2.fit_points(Rs, ts, p),
                [f.values if f is not None else None for f in ratio_field.fit_log_fields(samples, (240, 320),
                                                                                       temporal=1.0)])

    monkeypatch.setattr(parallel, "_cap", 1)
    one = run()
    monkeypatch.setattr(parallel, "_cap", 3)
    monkeypatch.setattr(point_fit, "MIN_PART_ROWS", 10)
    monkeypatch.setattr(static_fit, "MIN_PART_OBS", 10)
    monkeypatch.setattr(ratio_field, "MIN_PART_SAMPLES", 10)
    assert parallel.worker_threads() > 1 or parallel.cpu_count() == 1
    three = run()
    for a, b in zip(one[0], three[0], strict=True):
        assert np.array_equal(a, b, equal_nan=True)
    assert torch.equal(one[1], three[1])
    assert all((a is None and b is None) or np.array_equal(a, b) for a, b in zip(one[2], three[2], strict=True))
