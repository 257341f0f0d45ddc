"""pipeline.video_depth: the kNN searches done ahead on a spare thread change nothing but the time; and
optim.parallel.FramesAhead, which hands the frames between the two threads."""

import threading

import numpy as np
import pytest

from trackingworld.geometry import intrinsics_matrix
from trackingworld.optim.parallel import FramesAhead
from trackingworld.pipeline import video_depth as vd


def _tracks(seed=0, N=900, T=5, H=30, W=40):
    rng = np.random.default_rng(seed)
    uv = rng.uniform([0, 0], [W - 1, H - 1], (N, T, 2)).astype(np.float32)
    vis = rng.random((N, T)) < 0.7
    vis[:, 3] &= np.arange(N) < 5  # a frame with a few references only (fewer than k in its cells: none lost)
    vis[:, 4] = False  # and one with none: its ratio stays 1
    poses = np.tile(np.eye(4), (T, 1, 1))
    poses[:, 0, 3] = np.arange(T) * 0.1
    xyz = rng.uniform([-1, -1, 2], [1, 1, 4], (N, T, 3)).astype(np.float32)
    prior = rng.uniform(2, 4, (T, H, W)).astype(np.float32)
    K = intrinsics_matrix(35.0, 35.0, W / 2, H / 2)
    return uv, vis, xyz, poses, prior, K


@pytest.mark.parametrize("how", ["all ahead", "some ahead", "budget", "none ahead", "never run"])
def test_the_video_depth_with_the_search_ahead_is_the_one_without_to_the_bit(how):
    uv, vis, xyz, poses, prior, K = _tracks()
    ref, n_ref = vd.video_depth(uv, vis, xyz, poses, prior, K)
    budget = 2 * prior.shape[1] * prior.shape[2] * vd.K_NEAREST * 4 if how == "budget" else vd.AHEAD_BYTES
    ahead = vd.SearchAhead(uv, vis, prior.shape[1:], budget)
    if how in ("all ahead", "budget"):
        ahead.run()
    elif how == "some ahead":  # the thread stopped after two frames
        real = ahead.frames._work

        def two(t):
            if t == 1:
                ahead.frames.stop()
            return real(t)
        ahead.frames._work = two
        ahead.run()
    elif how == "none ahead":
        ahead.references()
    got, n_ahead = vd.video_depth(uv, vis, xyz, poses, prior, K, ahead)
    np.testing.assert_array_equal(got, ref)
    assert n_ref == 0 and n_ahead == {"all ahead": 5, "budget": 2, "some ahead": 2}.get(how, 0)
    assert (got[4] == prior[4]).all() and not (got[0] == prior[0]).all()


def test_the_video_depth_reads_the_prior_at_its_references_as_sampled_at_every_observation():
    # the prior sampled at the thinned references only: the maps of the ratios of the whole [N,T] sample, to the bit
    from trackingworld.optim.densify import ratio_maps
    from trackingworld.pipeline.fields import reference_ratios
    from trackingworld.pipeline.lift import sample_maps, sample_observations

    uv, vis, xyz, poses, prior, K = _tracks(3)
    D_raw = sample_maps(prior, uv, vis)
    n, t, ratio = reference_ratios(None, uv, vis, xyz, D_raw, poses, vd.REFERENCE_CELL_PX)
    np.testing.assert_array_equal(sample_observations(prior, uv, n, t), D_raw[n, t])
    shuffled = np.random.default_rng(0).permutation(len(n))  # any order of the observations
    np.testing.assert_array_equal(sample_observations(prior, uv, n[shuffled], t[shuffled]), D_raw[n, t][shuffled])
    ref = ratio_maps(t, uv[n, t], D_raw[n, t], ratio, prior.astype(np.float64), K, vd.K_NEAREST) * prior
    got, _ = vd.video_depth(uv, vis, xyz, poses, prior, K)
    np.testing.assert_array_equal(got, ref)


def test_a_non_finite_ratio_sets_the_search_ahead_aside():
    # the references of a frame are then not the ones searched ahead: the maps are made as without it
    uv, vis, xyz, poses, prior, K = _tracks(1)
    xyz[np.flatnonzero(vis[:, 0])[0], 0] = np.nan
    ref, _ = vd.video_depth(uv, vis, xyz, poses, prior, K)
    ahead = vd.SearchAhead(uv, vis, prior.shape[1:])
    ahead.run()
    got, _ = vd.video_depth(uv, vis, xyz, poses, prior, K, ahead)
    np.testing.assert_array_equal(got, ref)
    assert np.isfinite(got).all()


def test_frames_ahead_hands_each_frame_over_once_and_waits_for_the_one_in_hand():
    started, release = threading.Event(), threading.Event()

    def work(t):
        if t == 1:  # hold frame 1 in hand until the caller waits for it
            started.set()
            assert release.wait(5)
        if t == 3:
            raise RuntimeError("frame 3")
        return t * 10

    ahead = FramesAhead(work, range(5))
    thread = threading.Thread(target=ahead.run)
    thread.start()
    assert started.wait(5)
    assert ahead.take(0) == 0  # done ahead
    threading.Timer(0.2, release.set).start()
    assert ahead.take(1) == 10  # in hand: waited for
    thread.join(5)
    assert ahead.take(3) is None  # it raised there: the caller does it itself
    assert ahead.take(0) is None  # handed over once
    assert ahead.take(7) is None and ahead.done == 4
    late = FramesAhead(work, range(5))
    assert late.take(2) is None  # taken before the thread came to it: the thread leaves it
    late.stop()
    late.run()
    assert late.done == 0 and late.take(0) is None


def test_a_core_taken_leaves_the_others_to_the_splits(monkeypatch):
    from trackingworld.optim import parallel

    monkeypatch.setattr(parallel, "cpu_count", lambda: 4)
    assert parallel.worker_threads() == 4
    with parallel.core_taken():
        assert parallel.worker_threads() == 3
        seen = []
        t = threading.Thread(target=lambda: seen.append(parallel.worker_threads()))  # in every thread
        t.start()
        t.join()
        assert seen == [3]
        with parallel.core_taken(), parallel.core_taken(), parallel.core_taken():
            assert parallel.worker_threads() == 1  # never fewer than one
    assert parallel.worker_threads() == 4


def test_the_search_handed_to_a_thread_is_finished_by_the_video_depth():
    uv, vis, xyz, poses, prior, K = _tracks(2)
    ref, _ = vd.video_depth(uv, vis, xyz, poses, prior, K)
    ahead = vd.SearchAhead(uv, vis, prior.shape[1:])
    thread = threading.Thread(target=ahead.job())
    thread.start()
    got, n = vd.video_depth(uv, vis, xyz, poses, prior, K, ahead)  # waits for the thread's frame in hand
    thread.join(5)
    assert not thread.is_alive()
    np.testing.assert_array_equal(got, ref)
    assert 0 <= n <= 5
    from trackingworld.optim import parallel
    assert parallel._taken == 0  # its core given back
