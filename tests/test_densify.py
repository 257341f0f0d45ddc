"""optim.densify.propagate_ratio: the compiled weighted mean gives numpy's numbers to the last bit."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from trackingworld.geometry import intrinsics_matrix, unproject
from trackingworld.optim import densify


def _numpy_idw(ref_uv, ref_depth, ref_ratio, q_uv, q_depth, K, k, eps=1e-3):
    """The appendix's propagation written with numpy's array operations (the code the kernel replaced)."""
    k = min(k, len(ref_uv))
    _, idx = cKDTree(ref_uv).query(q_uv, k=k)
    idx = idx.reshape(len(q_uv), k)
    d = np.linalg.norm(unproject(q_uv, q_depth, K)[:, None] - unproject(ref_uv, ref_depth, K)[idx], axis=-1)
    w = 1.0 / (d + eps)
    return (w * ref_ratio[idx]).sum(1) / w.sum(1)


@pytest.mark.parametrize("k", [1, 3, 4, 7, 8, 16])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_the_propagated_ratio_is_numpys_to_the_last_bit(k, dtype):
    rng = np.random.default_rng(k)
    K = intrinsics_matrix(300.0, 290.0, 160.3, 120.7)
    ref_uv = rng.uniform([0, 0], [319, 239], (2000, 2)).astype(dtype)
    ref_depth = rng.uniform(1, 5, 2000).astype(dtype)
    ratio = rng.uniform(0.9, 1.1, 2000).astype(dtype)
    q_uv = rng.uniform([0, 0], [319, 239], (5000, 2)).astype(dtype)
    q_depth = rng.uniform(1, 5, 5000).astype(dtype)
    got = densify.propagate_ratio(ref_uv, ref_depth, ratio, q_uv, q_depth, K, k)
    np.testing.assert_array_equal(got, _numpy_idw(ref_uv, ref_depth, ratio, q_uv, q_depth, K, k))
    assert got.dtype == np.float64 and 0.9 <= got.min() and got.max() <= 1.1


def test_fewer_references_than_neighbours_and_a_flag_vote():
    K = intrinsics_matrix(300.0, 300.0, 160.0, 120.0)
    ref_uv = np.array([[10.0, 10.0], [200.0, 100.0]])
    flags = np.array([1.0, 0.0])  # a vote: the nearer reference (in 3D) wins
    q = np.array([[12.0, 10.0], [198.0, 101.0]])
    got = densify.propagate_ratio(ref_uv, np.full(2, 2.0), flags, q, np.full(2, 2.0), K, k=4)
    np.testing.assert_array_equal(got, _numpy_idw(ref_uv, np.full(2, 2.0), flags, q, np.full(2, 2.0), K, 4))
    assert got[0] > 0.5 > got[1]


@pytest.mark.parametrize("cell", [2, 4, 8])
def test_one_representative_per_cell_as_the_row_wise_unique_gives(cell):
    rng = np.random.default_rng(cell)
    q = np.c_[rng.integers(0, 30, 20000), rng.uniform(-5, 330, 20000), rng.uniform(-5, 245, 20000)]
    key = np.stack([q[:, 0], np.round(q[:, 1] / cell), np.round(q[:, 2] / cell)], 1).astype(np.int64)
    ref = np.sort(np.unique(key, axis=0, return_index=True)[1])  # the first track of each (frame, cell) key
    got = densify.cell_representatives(q, cell)
    assert len(ref) < len(q)
    np.testing.assert_array_equal(got, ref)
    assert len(densify.cell_representatives(q[:0], cell)) == 0
    np.testing.assert_array_equal(densify.cell_representatives(q, 1), np.arange(len(q)))


@pytest.mark.parametrize("dtype,cell,with_member", [(np.float32, 4.0, False), (np.float32, 3.0, True),
                                                    (np.float64, 2.5, True)])
def test_the_thinned_observations_are_the_frame_by_frame_numpy_ones(dtype, cell, with_member):
    rng = np.random.default_rng(int(cell * 10))
    N, T = 5000, 6
    uv = rng.uniform([-3, -3], [200, 120], (N, T, 2)).astype(dtype)
    uv[:50] = np.round(uv[:50])  # on cell borders too
    vis = rng.random((N, T)) < 0.6
    vis[:, 2] = False  # a frame no track is seen in
    member = rng.random(N) < 0.5 if with_member else None
    got = densify.thinned_observations(uv, vis, cell, member)
    ref = densify.thinned_observations_numpy(uv, vis, cell, member)
    for a, b in zip(got, ref, strict=True):
        np.testing.assert_array_equal(a, b)
    n, t = got
    assert 2 not in t and len(n) < vis.sum() and (np.diff(t) >= 0).all()
    assert member is None or member[n].all()
