import numpy as np

from trackingworld.geometry import in_image


def test_in_image_edges_and_margin():
    W, H = 8, 6
    uv = np.array([[-0.5, 0.0], [-0.51, 0.0], [7.5, 5.5], [7.51, 2.0], [3.0, 5.6], [0.0, 0.0], [7.0, 5.0]])
    assert in_image(uv, W, H).tolist() == [True, False, True, False, False, True, True]
    # margin 0.5: the pixels that can be sampled bilinearly, 0 .. W-1 and 0 .. H-1
    assert in_image(uv, W, H, margin=0.5).tolist() == [False, False, False, False, False, True, True]
    assert not in_image(np.array([[0.4, 3.0]]), W, H, margin=1.0)[0]
    assert in_image(np.array([[0.5, 3.0]]), W, H, margin=1.0)[0]


def _random_poses(rng, n):
    """``[n,4,4]`` rigid transforms: rotations from normalised quaternions, translations in metres."""
    from scipy.spatial.transform import Rotation

    out = np.tile(np.eye(4), (n, 1, 1))
    out[:, :3, :3] = Rotation.random(n, random_state=int(rng.integers(1 << 30))).as_matrix()
    out[:, :3, 3] = rng.normal(size=(n, 3))
    return out


def test_transform_and_camera_depths_against_matrix_products():
    """The column-wise transform and the z-only camera depths against plain 4x4 products, for the three ways the
    package broadcasts them: one pose per frame over tracks ``[T,4,4]`` x ``[N,T,3]``, one pose per point, one pose."""
    from trackingworld.geometry import camera_depths, invert_pose, transform

    rng = np.random.default_rng(3)
    N, T = 7, 5
    poses = _random_poses(rng, T)
    X = rng.normal(size=(N, T, 3)) * 4
    hom = np.concatenate([X, np.ones((N, T, 1))], -1)
    want = np.einsum("tij,ntj->nti", poses, hom)[..., :3]
    np.testing.assert_allclose(transform(poses[None], X), want, atol=1e-12)
    np.testing.assert_allclose(transform(poses, X), want, atol=1e-12)  # [T,4,4] broadcast over N
    w2c = invert_pose(poses)
    np.testing.assert_allclose(camera_depths(X, poses), np.einsum("tj,ntj->nt", w2c[:, 2], hom), atol=1e-12)
    per_point = _random_poses(rng, N)
    np.testing.assert_allclose(transform(per_point, X[:, 0]),
                               np.einsum("nij,nj->ni", per_point, hom[:, 0])[:, :3], atol=1e-12)
    np.testing.assert_allclose(transform(poses[2], X[:, 2]), (hom[:, 2] @ poses[2].T)[:, :3], atol=1e-12)
