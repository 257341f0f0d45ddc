"""The static tracks' depth target outside stage 2 (the prior times the optimised points' field) and the refit
of the static points against it."""

import numpy as np
import torch

from trackingworld.config import OptimConfig
from trackingworld.geometry import intrinsics_matrix, invert_pose, project, transform, unproject
from trackingworld.optim import lie, static_tests
from trackingworld.optim.ratio_field import fit_log_field
from trackingworld.pipeline import fields as prior_fields
from trackingworld.pipeline import world

K = intrinsics_matrix(300.0, 300.0, 160.0, 120.0)


def test_field_image_is_the_field_at_every_pixel(rng):
    f = fit_log_field(rng.uniform([0, 0], [319, 239], (500, 2)), rng.normal(0, 0.05, 500), (240, 320))
    ys, xs = np.mgrid[0:240, 0:320]
    want = f(np.stack([xs.ravel(), ys.ravel()], 1)).reshape(240, 320)
    img = f.image()
    assert img.shape == (240, 320) and img.dtype == np.float32
    np.testing.assert_allclose(img, want, atol=1e-6)


def test_corrected_prior_scales_the_visible_observations_by_their_frames_field(rng):
    N, T, shape = 400, 3, (240, 320)
    D = rng.uniform(2, 6, (N, T)).astype(np.float32)
    uv = rng.uniform([0, 0], [319, 239], (N, T, 2))
    vis = rng.random((N, T)) < 0.7
    fields = [fit_log_field(rng.uniform([0, 0], [319, 239], (300, 2)), rng.normal(0.1 * t, 0.05, 300), shape)
              for t in range(T)]
    fields[1] = None
    out = prior_fields.corrected_prior(D, uv, vis, fields)
    want = D.copy()
    for t in (0, 2):
        want[vis[:, t], t] *= np.exp(fields[t](uv[vis[:, t], t]))
    np.testing.assert_allclose(out, want, rtol=5e-4)  # the image sampled between pixels: the same field
    assert out.dtype == D.dtype and not np.shares_memory(out, D)
    assert not np.allclose(out[vis[:, 2], 2], D[vis[:, 2], 2])


def test_refit_against_the_corrected_prior_places_short_baseline_points_better(rng):
    """Points seen over a 3 cm baseline at 4-8 m (parallax a few pixels) under a prior off by a per-frame scale
    and a smooth warp of +-8%: the field of well-placed reference points (here the true depths, as the bundle
    adjustment of long tracks gives them) corrects the prior, and the refit with a strong depth weight puts the
    points several times closer to the truth than the stage-2 weights against the raw prior do."""
    T, N = 4, 3000
    c2w = np.tile(np.eye(4), (T, 1, 1))
    c2w[:, 0, 3] = 0.01 * np.arange(T)
    uv0 = rng.uniform([0, 0], [319, 239], (N, 2))
    X = unproject(uv0, rng.uniform(4, 8, N), K)
    uv, z = project(transform(invert_pose(c2w)[None], np.repeat(X[:, None], T, 1)), K)
    uv = uv + rng.normal(0, 0.3, uv.shape)  # a 2D tracker's noise
    x, y = uv[..., 0] / 320, uv[..., 1] / 320
    warp = 0.08 * np.cos(2 * np.pi * (0.6 * x - 0.4 * y) + 0.4 * np.arange(T)) + rng.normal(0, 0.05, T)
    D = (z * np.exp(warp + rng.normal(0, 0.02, z.shape))).astype(np.float32)
    vis = np.ones((N, T), bool)
    refs = np.arange(0, N, 3)
    xyz_ref = np.repeat(X[:, None], T, 1).astype(np.float32)
    fields = prior_fields.static_fields(refs, uv, vis, xyz_ref, D, c2w, (240, 320), (8, 6), 0.01)
    R, t = lie.c2w_to_w2c(c2w, torch.float64, "cpu")
    cfg = OptimConfig()
    err = {}
    for name, prior, lam, iters in (("stage-2 weights, raw prior", D, cfg.lambda_dc, 6),
                                    ("refit", prior_fields.corrected_prior(D, uv, vis, fields), cfg.static_refit_dc,
                                     world.REFIT_ITERS)):
        xyz = np.zeros((N, T, 3), np.float32)
        static_tests.fit_static_points(np.arange(N), uv, prior, vis, xyz, K, R, t, OptimConfig(lambda_dc=lam), "cpu",
                                 iters)
        err[name] = np.median(np.abs(np.linalg.norm(xyz[:, 0] - X, axis=1) / X[:, 2]))
    assert err["refit"] < 0.02 and err["refit"] < 0.4 * err["stage-2 weights, raw prior"], err


def test_the_static_fit_reads_more_of_a_long_tracks_frames_when_asked(rng):
    """``static_fit_frames``: a point seen in 40 frames under 0.5 px of tracker noise and a prior with 5% noise per
    frame is fitted from about that many of its frames, spread over its span; reading all 40 averages four times
    the observations and places it about twice as close as reading 10."""
    T, N = 40, 2000
    c2w = np.tile(np.eye(4), (T, 1, 1))
    c2w[:, 0, 3] = 0.005 * np.arange(T)  # a 20 cm slide
    X = unproject(rng.uniform([0, 0], [319, 239], (N, 2)), rng.uniform(4, 8, N), K)
    uv, z = project(transform(invert_pose(c2w)[None], np.repeat(X[:, None], T, 1)), K)
    uv = uv + rng.normal(0, 0.5, uv.shape)
    D = (z * np.exp(rng.normal(0, 0.05, z.shape))).astype(np.float32)
    vis = np.ones((N, T), bool)
    R, t = lie.c2w_to_w2c(c2w, torch.float64, "cpu")
    err = {}
    for frames in (10, 0):
        xyz = np.zeros((N, T, 3), np.float32)
        cfg = OptimConfig(lambda_dc=OptimConfig.static_refit_dc, static_fit_frames=frames)
        static_tests.fit_static_points(np.arange(N), uv, D, vis, xyz, K, R, t, cfg, "cpu", world.REFIT_ITERS)
        err[frames] = np.median(np.abs(xyz[:, 0, 2] / X[:, 2] - 1))
    assert err[0] < 0.7 * err[10]
