"""Voxel grouping (service.tracking.voxels): the groups of np.unique(axis=0) and the sums of np.add.at, bit for bit."""

import numpy as np

from service.tracking.voxels import group_sums, voxel_groups


def test_same_groups_and_sums_as_unique_rows_and_add_at():
    rng = np.random.default_rng(3)
    P = rng.normal(0.0, 0.05, (5000, 3)) + [0.3, -0.2, 0.01]  # negative and positive keys
    key = np.floor(P / 0.003).astype(np.int64)
    inv, cnt = voxel_groups(key)
    _, inv0, cnt0 = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    np.testing.assert_array_equal(inv, inv0.reshape(-1))
    np.testing.assert_array_equal(cnt, cnt0)
    S0 = np.zeros((len(cnt0), 3))
    np.add.at(S0, inv0.reshape(-1), P)
    assert np.array_equal(group_sums(inv, P, len(cnt)), S0)  # bit for bit, not merely close


def test_edge_cases():
    inv, cnt = voxel_groups(np.zeros((0, 3), np.int64))
    assert inv.shape == (0,) and cnt.shape == (0,)
    key = np.array([[0, 0, 0], [2**40, -(2**40), 5], [0, 0, 0]], np.int64)  # too wide for one code: rows sorted
    inv, cnt = voxel_groups(key)
    np.testing.assert_array_equal(inv, [0, 1, 0])
    np.testing.assert_array_equal(cnt, [2, 1])
