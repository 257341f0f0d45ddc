"""The masks' cores keep their dynamic label (``OptimConfig.mask_core_px``, ``optim.labels.depth_in_mask``)."""

import numpy as np
import pytest

from test_own_test import K, _wall_scene, masked_box
from trackingworld.config import OptimConfig
from trackingworld.errors import InputError
from trackingworld.optim.labels import depth_in_mask
from trackingworld.pipeline import world
from trackingworld.pipeline.world import check_optim, resolve_vote_core
from trackingworld.tracking2d.base import TrackResult


def test_depth_in_mask_is_the_distance_to_the_nearest_pixel_outside_in_the_query_frame():
    masks = np.zeros((2, 40, 60), bool)
    masks[0, 10:30, 10:50] = True  # frame 0: a 40 x 20 box
    tracks = np.zeros((4, 2, 2))
    tracks[:, 0] = [[30, 20], [12, 20], [5, 5], [30, 20]]  # centre, 2 px in from the left edge, outside, centre
    got = depth_in_mask(tracks, np.array([0, 0, 0, 1]), masks)
    assert abs(got[0] - 10) <= 0.5  # 10 px to the rows above and below the box
    assert abs(got[1] - 3) <= 0.5  # pixel 12 is the third column in: pixel 9 is the nearest outside
    assert got[2] == 0 and got[3] == 0  # outside; frame 1 has no mask


def test_a_static_wall_under_a_wrong_mask_keeps_its_core_dynamic_and_its_band_static():
    """A (wrong) dynamic mask over a 56 x 52 px patch of a static wall: with the masks' cores kept, the tracks 10 px
    or more inside stay dynamic and those of the band within it are static (the as-static test); without, all of
    the sure-dynamic region is static."""
    tr, prior, _, slipped, mover, _ = _wall_scene()
    masks, sure = masked_box(prior.shape, tr.queries, (20, 76, 10, 62), margin=3)
    x, y = tr.queries[:, 1], tr.queries[:, 2]
    inside = np.minimum.reduce([x - 19, 76 - x, y - 9, 62 - y])  # px to the nearest pixel outside the box
    judged = np.ones(len(x), bool)
    judged[slipped] = judged[mover] = False
    core = judged & (inside >= 11)  # clear of the distance transform's rounding at 10
    band = judged & sure & (inside <= 8)
    on = world.optimise(tr, prior, masks, K, OptimConfig(verbose=False, mask_core_px=10), {})
    off = world.optimise(tr, prior, masks, K, OptimConfig(verbose=False, mask_core_px=0), {})
    assert core.sum() > 500 and band.sum() > 500
    assert on["is_dynamic"][core].all() and not on["is_dynamic"][band].any()
    assert not off["is_dynamic"][core | band].any()
    assert on["info"]["classify"]["core"] >= core.sum()


def test_a_negative_core_depth_is_refused():
    with pytest.raises(InputError, match="mask_core_px -1.0: the depth inside the masks"):
        check_optim(OptimConfig(mask_core_px=-1.0))
    check_optim(OptimConfig(mask_core_px=0.0))


def test_a_masked_mover_seen_in_few_frames_keeps_its_core_dynamic_through_the_vote():
    """A patch of the wall sliding down 2 px a frame (10 cm at 5 m), its tracks seen in frames 0-5 only (a mover
    that leaves early), under a coarse mask 6 px wider than it. All its tracks are seen in at most ``vote_short``
    frames, so the vote of the short tracks judges them, and its only long voters are the static wall's. The
    tracks 10 px or more inside the mask keep the mask's label (before, the whole patch came out static); the
    patch's tracks nearer the mask's border, and the wall's inside the mask, take the vote of the wall: static."""
    from test_own_test import MOVER_REGION, _slow_mover_scene

    tr, prior, short_mover, long_mover, _ = _slow_mover_scene(short_len=6)
    patch = np.r_[short_mover, long_mover]
    tracks, vis = tr.tracks.copy(), tr.visible.copy()
    tracks[patch, :, 1] += 1.2 * np.arange(tracks.shape[1])  # 0.8 + 1.2 = 2 px a frame
    vis[patch, 6:] = False
    tr = TrackResult(tracks, vis, tr.confidence, tr.queries)
    x0, x1, y0, y1 = MOVER_REGION
    masks, sure = masked_box(prior.shape, tr.queries, (x0 - 6, x1 + 6, y0 - 6, y1 + 6), margin=3)
    depth = depth_in_mask(tr.tracks, np.zeros(len(vis), np.int64), masks)
    core = patch[depth[patch] >= 10]
    wall = np.setdiff1d(np.flatnonzero(sure), patch)  # the static wall inside the mask, around the patch
    out = world.optimise(tr, prior, masks, K, OptimConfig(verbose=False), {})["is_dynamic"]
    assert vis[patch].sum(1).max() <= OptimConfig().vote_short and len(core) >= 200
    assert out[core].all()
    assert len(wall) >= 200 and not out[wall].any()
    # --vote-core off (what auto gives the weight-free motion masks): the vote takes the core too, as before
    off = world.optimise(tr, prior, masks, K, OptimConfig(verbose=False, vote_core="off"), {})["is_dynamic"]
    assert not off[core].any()


def test_the_vote_keeps_the_cores_with_masks_of_objects_only():
    assert resolve_vote_core("auto", "objects") == "on" and resolve_vote_core("auto", "motion") == "off"
    assert resolve_vote_core("off", "objects") == "off" and resolve_vote_core("on", "motion") == "on"
    with pytest.raises(InputError, match="vote_core"):
        check_optim(OptimConfig(vote_core="maybe"))
