"""Static tracks whose 2D track slips off their point: the run test (``optim.slip``, ``OptimConfig.slip_run``)."""

import numpy as np

from test_own_test import REGION, K, _slip_late, _wall_scene, masked_box
from trackingworld.config import OptimConfig
from trackingworld.optim.slip import frames_around, long_runs, run_around
from trackingworld.pipeline import world
from trackingworld.tracking2d.base import TrackResult


def test_frames_around_the_query_frame_count_visible_frames_only():
    vis = np.array([[1, 1, 0, 1, 1, 1, 0, 1],
                    [1, 1, 1, 1, 1, 1, 1, 1],
                    [0, 0, 0, 0, 0, 1, 1, 1]], bool)
    got = frames_around(vis, np.array([3, 0, 7]), 2)
    np.testing.assert_array_equal(got, [[1, 1, 0, 1, 1, 1, 0, 0],   # two visible either side of frame 3
                                        [1, 1, 1, 0, 0, 0, 0, 0],   # at the start: the two after only
                                        [0, 0, 0, 0, 0, 1, 1, 1]])


def test_the_run_around_the_query_frame_stops_at_the_first_bad_frame_either_side():
    vis = np.array([[1, 1, 1, 1, 1, 1, 1, 1],
                    [1, 1, 0, 1, 1, 1, 0, 1],
                    [1, 1, 1, 1, 1, 1, 1, 1],
                    [1, 1, 1, 1, 1, 1, 1, 1]], bool)
    bad = np.zeros_like(vis)
    bad[0, [1, 6]] = True
    bad[1, 2] = True  # a bad frame that is not visible does not interrupt the run
    bad[2, 4] = True  # bad at the query frame: no run
    run = run_around(vis, bad, np.array([3, 4, 4, 0]))
    np.testing.assert_array_equal(run, [[0, 0, 1, 1, 1, 1, 0, 0],
                                        [1, 1, 0, 1, 1, 1, 0, 1],
                                        [0, 0, 0, 0, 0, 0, 0, 0],
                                        [1, 1, 1, 1, 1, 1, 1, 1]])
    np.testing.assert_array_equal(long_runs(run, vis, 0.5), [True, True, False, True])
    np.testing.assert_array_equal(long_runs(run, vis, 0.6), [False, True, False, True])


def test_a_masked_static_track_that_slips_late_is_static_in_its_run():
    """Tracks on the wall inside a (wrong) dynamic mask: those that slip off their point in their last 4 of 8
    frames are static, seen in frames 0-3 only, with the run test; dynamic without it. Those that slip in 6 of 8
    and a track moving throughout are dynamic either way."""
    tr, prior, _, _, mover, others = _wall_scene()
    masks, box = masked_box(prior.shape, tr.queries, REGION)
    inner = others[box[others]]
    late4, late6 = inner[:10], inner[10:20]
    tracks = tr.tracks.copy()
    _slip_late(tracks, late4, 4)
    _slip_late(tracks, late6, 6)
    vis = tr.visible & (tracks[..., 0] <= 95)
    tr = TrackResult(tracks, vis, tr.confidence, tr.queries)
    on = world.optimise(tr, prior, masks, K, OptimConfig(verbose=False), {})
    off = world.optimise(tr, prior, masks, K, OptimConfig(verbose=False, slip_run=0), {})
    assert not on["is_dynamic"][late4].any() and off["is_dynamic"][late4].all()
    assert on["visible"][late4][:, :4].all() and not on["visible"][late4][:, 4:].any()
    assert on["is_dynamic"][late6].all() and off["is_dynamic"][late6].all()
    assert on["is_dynamic"][mover] and off["is_dynamic"][mover]
    assert on["info"]["classify"]["slipped"] >= len(late4)
    # the run's static points are where the wall is: within 2% of the prior's depth at the query frame
    z = on["xyz"][late4, 0, 2]
    x, y = tr.queries[late4, 1].astype(int), tr.queries[late4, 2].astype(int)
    np.testing.assert_allclose(z, prior[0, y, x], rtol=0.02)
