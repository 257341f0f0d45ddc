"""Dynamic-labelled tracks that are static points dragged by a mover's flow: the static hypothesis checked in the
images (``optim.photo_static``, ``OptimConfig.photo_static_grey``)."""

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from trackingworld.config import OptimConfig
from trackingworld.geometry import invert_pose, project, transform, unproject
from trackingworld.image import blurred_frames
from trackingworld.io.frames import read_frames
from trackingworld.io.priors import load_masks
from trackingworld.optim.labels import DYNAMIC, STATIC, mask_regions
from trackingworld.optim.photo_static import MASK_MARGIN_PX, depth_scales, near_masks, static_hypothesis
from trackingworld.pipeline.static_side import photo_rescue

Q = 5  # the query frame: movers on both sides of it in time


@pytest.fixture(scope="module")
def scene(tiny_scene):
    g = dict(np.load(tiny_scene / "gt.npz"))
    frames, _ = read_frames(tiny_scene / "input" / "frames")
    masks = load_masks(tiny_scene / "input" / "masks", len(frames))
    return g, frames, masks


def _open(masks):
    """Where the static hypothesis is tested: the masks' sure-static region, as the pipeline reads it."""
    return mask_regions(masks, MASK_MARGIN_PX)[0]


def _pixels(sel):
    ys, xs = np.nonzero(sel)
    return np.stack([xs, ys], 1).astype(np.float32)


def test_background_beside_the_masked_movers_passes_and_the_movers_do_not(scene):
    """With the exact depth and poses: a share of the background pixels inside the coarse masks shows its query
    colour wherever its static point projects outside them; the masked movers' pixels almost never do."""
    g, frames, masks = scene
    blur, open_ = blurred_frames(frames), _open(masks)
    share = {}
    for name, sel in (("background", masks[Q] & ~g["dynamic"][Q]), ("mover", g["dynamic"][Q] & ~g["bg_mover"][Q])):
        uv = _pixels(sel)
        qf = np.full(len(uv), Q)
        static, X, pix, seen = static_hypothesis(uv, g["depth"][Q][sel].astype(np.float64), qf, g["poses_c2w"],
                                                 g["K"], blur, open_)
        share[name] = static.mean()
        keep = np.flatnonzero(static)
        # a static one: its point projects onto its query pixel, its 2D track is that projection, seen there
        np.testing.assert_allclose(pix[:, Q], uv[keep])
        assert seen[:, Q].all()
        w2c = invert_pose(g["poses_c2w"])
        for t in range(len(frames)):
            px, _ = project(transform(w2c[t], X[keep]), g["K"])
            np.testing.assert_allclose(pix[:, t], px, atol=1e-3) if t != Q else None
            assert (seen[:, t] <= (open_[t][np.rint(px[:, 1]).clip(0, 95).astype(int),
                                            np.rint(px[:, 0]).clip(0, 127).astype(int)] | (t == Q))).all()
    assert len(_pixels(masks[Q] & ~g["dynamic"][Q])) > 500
    assert share["background"] > 0.2
    assert share["mover"] < 0.01


def test_a_stricter_share_or_colour_finds_fewer(scene):
    g, frames, masks = scene
    sel = masks[Q] & ~g["dynamic"][Q]
    uv, z = _pixels(sel), g["depth"][Q][sel].astype(np.float64)
    args = (uv, z, np.full(len(uv), Q), g["poses_c2w"], g["K"], blurred_frames(frames), _open(masks))
    loose = static_hypothesis(*args, grey=12.0, frac=0.6)[0].sum()
    default = static_hypothesis(*args)[0].sum()
    strict = static_hypothesis(*args, grey=4.0, frac=0.8)[0].sum()
    assert loose >= default > strict


def test_photo_rescue_turns_dragged_background_tracks_into_static_points(scene):
    """Background tracks inside the masks whose 2D tracks drift 1.5 px a frame (dragged): those that pass become
    static, hold one world point, and their 2D tracks become its projection; the caller's arrays are not written."""
    g, frames, masks = scene
    T = len(frames)
    sel = masks[Q] & ~g["dynamic"][Q]
    uvq = _pixels(sel)
    N = len(uvq)
    uv = (uvq[:, None] + 1.5 * (np.arange(T) - Q)[None, :, None] * np.float32([1, 0])).astype(np.float32)
    vis = np.ones((N, T), bool)
    qf = np.full(N, Q)
    D = np.repeat(g["depth"][Q][sel][:, None], T, 1).astype(np.float32)
    dynamic = np.ones(N, bool)
    xyz = np.zeros((N, T, 3), np.float32)
    uv0, vis0 = uv.copy(), vis.copy()
    info = {}
    uv2, vis2, moved = photo_rescue(uv, vis, qf, D, g["poses_c2w"], g["K"], frames, masks, OptimConfig(), dynamic,
                                    xyz, info)
    assert info["photo_static"] == {"tested": N, "static": len(moved)} and len(moved) > 0.2 * N
    np.testing.assert_array_equal(uv, uv0)
    np.testing.assert_array_equal(vis, vis0)
    assert not dynamic[moved].any() and dynamic[np.setdiff1d(np.arange(N), moved)].all()
    np.testing.assert_array_equal(xyz[moved], np.repeat(xyz[moved][:, :1], T, 1))  # one point each
    true = transform(g["poses_c2w"][Q], unproject(uvq.astype(np.float64), g["depth"][Q][sel], g["K"]))
    assert np.median(np.linalg.norm(xyz[moved, 0] - true[moved], axis=1)) < 0.05  # metres: the right point
    w2c = invert_pose(g["poses_c2w"])
    for t in range(T):
        px, _ = project(transform(w2c[t], xyz[moved, t].astype(np.float64)), g["K"])
        np.testing.assert_allclose(uv2[moved, t], px, atol=1e-2)
    assert vis2[moved, Q].all() and vis2[moved].sum() < vis[moved].sum()
    # with the mask labels, the tracks the masks call static are not tested (a missed mover's slide)
    labels = np.where(np.arange(N) % 2 == 0, STATIC, DYNAMIC).astype(np.int8)
    dyn = np.ones(N, bool)
    info = {}
    moved2 = photo_rescue(uv, vis, qf, D, g["poses_c2w"], g["K"], frames, masks, OptimConfig(), dyn, xyz.copy(), info,
                          labels)[2]
    assert info["photo_static"]["tested"] == (labels != STATIC).sum()
    np.testing.assert_array_equal(moved2, moved[moved % 2 == 1])
    # a patch test as well (OptimConfig.photo_static_patch): a strict one takes back fewer of them
    dyn = np.ones(N, bool)
    strict = photo_rescue(uv, vis, qf, D, g["poses_c2w"], g["K"], frames, masks, OptimConfig(photo_static_patch=1.0),
                          dyn, xyz.copy(), {})[2]
    assert len(strict) < len(moved)
    off = OptimConfig(photo_static_grey=0.0)
    dyn = np.ones(N, bool)
    same = photo_rescue(uv, vis, qf, D, g["poses_c2w"], g["K"], frames, masks, off, dyn, xyz.copy(), {})
    assert same[0] is uv and same[1] is vis and len(same[2]) == 0 and dyn.all()


def test_near_masks_finds_the_tracks_a_mask_passes():
    """A mask square in frame 1 only: a track that comes within 3 px of it there is near, one seen there 6 px away
    or hidden there is not."""
    masks = np.zeros((3, 40, 40), bool)
    masks[1, 10:20, 10:20] = True
    uv = np.zeros((3, 3, 2), np.float32)
    uv[:, :] = [30.0, 30.0]
    uv[0, 1] = [22.0, 15.0]  # 3 px right of the square's last column (19)
    uv[1, 1] = [25.0, 15.0]  # 6 px right
    uv[2, 1] = [22.0, 15.0]
    vis = np.ones((3, 3), bool)
    vis[2, 1] = False  # hidden in the mask's frame
    np.testing.assert_array_equal(near_masks(uv, vis, masks, 4.0), [True, False, False])
    np.testing.assert_array_equal(near_masks(uv, vis, masks, 8.0), [True, True, False])


def test_depth_scales_are_symmetric_about_one():
    np.testing.assert_allclose(depth_scales(0.04), [0.96, 0.98, 1.0, 1.02, 1.04])
    assert len(depth_scales(0.1)) == 11 and depth_scales(0.0).tolist() == [1.0]


def test_the_patch_test_tells_a_sliding_texture_from_a_still_one():
    """Fine stripes (+-5.8 grey levels, 8 px period) on grey, a camera that does not move: where the stripes stay,
    the point passes with and without the patch test; where they slide half a period (a mover over a smooth
    texture), each pixel's colour stays within 12 grey levels of its query colour, so the colour test still
    passes, and the 5x5 patch does not."""
    T, H, W = 4, 32, 48
    xs = np.arange(W)
    still = np.repeat((128 + 5.8 * np.sin(2 * np.pi * xs / 8))[None, :, None], H, 0)
    frames = np.repeat(np.repeat(still[None], T, 0), 3, 3).astype(np.float32)
    slid = frames.copy()
    slid[1:] = np.roll(frames[1:], 4, axis=2)  # half a period in frames 1-3
    K = np.array([[40.0, 0, W / 2], [0, 40.0, H / 2], [0, 0, 1]])
    poses = np.tile(np.eye(4), (T, 1, 1))
    uv = np.stack(np.meshgrid(np.arange(8.0, 40.0), np.arange(8.0, 24.0)), -1).reshape(-1, 2).astype(np.float32)
    z = np.full(len(uv), 5.0)
    qf = np.zeros(len(uv), int)
    open_ = np.ones((T, H, W), bool)
    for imgs, passes_patch in ((frames, True), (slid, False)):
        args = (uv, z, qf, poses, K, imgs, open_)
        assert static_hypothesis(*args, scales=np.ones(1))[0].all()  # the colour alone: both pass
        static = static_hypothesis(*args, scales=np.ones(1), patch_grey=4.0)[0]
        assert static.all() if passes_patch else not static.any()


def _smooth_texture(H: int, W: int, amplitude: float, seed: int) -> np.ndarray:
    """[H,W] grey levels: smoothed noise (sigma 3 px, wrapping) within 128 +- ``amplitude``."""
    tex = gaussian_filter(np.random.default_rng(seed).standard_normal((H, W)), 3.0, mode="wrap")
    return 128 + amplitude * tex / np.abs(tex).max()


def test_a_track_seen_away_from_the_projection_must_show_the_query_colour_worse():
    """A smooth random texture (within +-5.5 grey levels), a camera that does not move. Where the texture slides
    3 px a frame and the track follows it (a mover the masks missed, tracked right), the projection of the static
    point shows colours within 12 grey levels of the query colour, so the colour alone takes the track for a static
    point; its own pixel shows the query colour exactly, so with the track given it is not. Where the texture stays
    and the track was dragged 3 px a frame off its point, the projection shows the query colour better than the
    track's pixel: a static point either way. A track within the distance of its projection is judged as before."""
    T, H, W = 4, 40, 64
    tex = _smooth_texture(H, W, 5.5, seed=0)
    still = np.repeat(np.repeat(tex[None, :, :, None], T, 0), 3, 3).astype(np.float32)
    slid = np.stack([np.roll(still[0], 3 * t, axis=1) for t in range(T)])
    K = np.array([[40.0, 0, W / 2], [0, 40.0, H / 2], [0, 0, 1]])
    poses = np.tile(np.eye(4), (T, 1, 1))
    uv = np.stack(np.meshgrid(np.arange(12.0, 40.0), np.arange(10.0, 30.0)), -1).reshape(-1, 2).astype(np.float32)
    n = len(uv)
    z, qf, open_ = np.full(n, 5.0), np.zeros(n, int), np.ones((T, H, W), bool)
    follow = (uv[:, None] + 3.0 * np.arange(T)[None, :, None] * np.float32([1, 0])).astype(np.float32)
    vis = np.ones((n, T), bool)
    for imgs, static_with_track in ((slid, False), (still, True)):
        args = (uv, z, qf, poses, K, imgs, open_)
        assert static_hypothesis(*args, scales=np.ones(1))[0].all()  # the colour alone: both pass
        static = static_hypothesis(*args, scales=np.ones(1), track=(follow, vis, 2.0))[0]
        assert static.all() if static_with_track else not static.any()
    # a track 1 px from its projection is not compared: the sliding texture passes as with the colour alone
    near = (uv[:, None] + np.float32([1, 0])).repeat(T, 1)
    near[:, 0] = uv
    assert static_hypothesis(uv, z, qf, poses, K, slid, open_, scales=np.ones(1), track=(near, vis, 2.0))[0].all()


def test_photo_rescue_leaves_a_tracked_sliding_texture_dynamic_by_default():
    """The pipeline's step with the setting wired through: tracks that follow a smooth texture sliding 3 px a frame
    (no masks, so every frame is tested) stay dynamic with the default OptimConfig, and are taken for static points
    with ``photo_static_track_px=0`` (stop 60's test, the projection alone)."""
    T, H, W = 4, 40, 64
    tex = _smooth_texture(H, W, 5.0, seed=1)
    frames = np.stack([np.repeat(np.roll(tex, 3 * t, axis=1)[:, :, None], 3, 2) for t in range(T)])
    frames = np.rint(frames).astype(np.uint8)
    K = np.array([[40.0, 0, W / 2], [0, 40.0, H / 2], [0, 0, 1]])
    poses = np.tile(np.eye(4), (T, 1, 1))
    uvq = np.stack(np.meshgrid(np.arange(12.0, 40.0, 2), np.arange(10.0, 30.0, 2)), -1).reshape(-1, 2)
    n = len(uvq)
    uv = (uvq[:, None] + 3.0 * np.arange(T)[None, :, None] * np.array([1.0, 0.0])).astype(np.float32)
    vis, qf = np.ones((n, T), bool), np.zeros(n, int)
    D = np.full((n, T), 5.0, np.float32)
    masks = np.zeros((T, H, W), bool)
    found = {}
    for px in (2.0, 0.0):
        dynamic, xyz = np.ones(n, bool), np.zeros((n, T, 3), np.float32)
        found[px] = len(photo_rescue(uv, vis, qf, D, poses, K, frames, masks, OptimConfig(photo_static_track_px=px),
                                     dynamic, xyz, {})[2])
    assert OptimConfig().photo_static_track_px == 2.0
    assert found[0.0] > 0.9 * n and found[2.0] < 0.05 * n


@pytest.mark.parametrize("depth_kind", [None, "float32", "float64"])
def test_the_compiled_projection_test_gives_numpys_pixels_and_flags(depth_kind):
    from scipy.spatial.transform import Rotation

    from trackingworld.optim import photo_static as ps

    rng = np.random.default_rng(7)
    H, W = 60, 80
    K = np.array([[70.0, 0.0, 40.2], [0.0, 68.0, 29.7], [0.0, 0.0, 1.0]])
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.05, -0.1, 0.02]).as_matrix()
    T[:3, 3] = [0.1, -0.05, 0.2]
    X = rng.uniform([-3, -2, -1], [3, 2, 6], (20000, 3))
    # points that land on the image's corners and edges exactly, and at the camera's centre plane
    corners = np.array([[0.0, 0.0], [W - 1, H - 1], [W - 1, 0.0], [-1e-3, 5.0], [W - 1 + 1e-3, 5.0]])
    cam = np.c_[(corners - K[:2, 2]) / np.diag(K)[:2] * 2.0, np.full(len(corners), 2.0)]
    Tinv = np.linalg.inv(T)
    X[: len(corners)] = cam @ Tinv[:3, :3].T + Tinv[:3, 3]
    X[len(corners):len(corners) + 3] = Tinv[:3, 3]  # the camera centre: z = 0
    open_t = rng.random((H, W)) < 0.7
    depth = None if depth_kind is None else rng.uniform(0.5, 6, (H, W)).astype(depth_kind)
    uv, tested = ps._project_and_test(X, T, K, open_t, depth, 0.9)
    uv_ref, tested_ref = ps._project_and_test_numpy(X, T, K, open_t, depth, 0.9)
    np.testing.assert_array_equal(uv, uv_ref)
    np.testing.assert_array_equal(tested, tested_ref)
    assert uv.dtype == np.float32 and 0.02 < tested.mean() < 0.5
