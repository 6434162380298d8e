"""Gauge of the body frame from the frames at rest (service.tracking.gauge)."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from service.tracking.gauge import gauge_pose, rest_frames, robust_mean_pose
from service.tracking.types import TrackingConfig
from service.transforms import make_X, rotation_angle, so3_exp


def _yaw(deg, t=(0.0, 0.0, 0.0)):
    return make_X(so3_exp(np.radians([0.0, 0.0, deg])), np.array(t))


def test_robust_mean_pose_ignores_one_outlier():
    Xs = [_yaw(a, (0, 0, t)) for a, t in ((1.0, 0.001), (1.2, 0.0012), (0.9, 0.0009), (30.0, 0.05), (1.1, 0.0011))]
    M = robust_mean_pose(Xs)
    assert np.degrees(rotation_angle(M[:3, :3].T @ so3_exp(np.radians([0, 0, 1.05])))) < 0.1
    assert abs(M[2, 3] - 0.00105) < 2e-4


def test_gauge_from_rest_frames_removes_frame0_error():
    # frame 0's registration is 2° off; the still frames 1..8 are registered within ±0.3° of the true pose (0°)
    rng = np.random.default_rng(0)
    X = np.stack([_yaw(0.0)] + [_yaw(rng.uniform(-0.3, 0.3)) for _ in range(8)])
    X0_hat = _yaw(2.0)
    G = gauge_pose(X0_hat, X, list(range(1, 9)))
    assert np.degrees(rotation_angle(G[:3, :3])) < 0.35
    assert np.allclose(gauge_pose(X0_hat, X, []), X0_hat)
    assert gauge_pose(None, X, []) is None


def test_rest_frames_end_where_the_robot_reaches_the_object():
    Q = np.random.default_rng(1).uniform(-0.05, 0.05, (500, 3))  # model points in O
    tree = cKDTree(Q)
    n = 12
    X = np.stack([_yaw(0.0, (0.3, 0.0, 0.05))] * n)
    # the sphere (radius 2 cm) approaches along x: 25, 23, ... cm from the object's centre
    p = np.stack([[0.3 + 0.25 - 0.02 * k, 0.0, 0.05] for k in range(n)])
    tracked = np.ones(n, bool)
    npts = np.full(n, 100)
    got = rest_frames(X, tracked, npts, p, 0.02, tree, 50, 0.02, 5.0, 0.01, 40)
    d = np.array([tree.query(pp - X[0][:3, 3])[0] for pp in p])
    first_near = int(np.argmax(d < 0.04))
    assert got == list(range(1, first_near))
    assert rest_frames(X, tracked, npts, p, 0.02, tree, 3, 0.02, 5.0, 0.01, 40) == [1, 2, 3]
    assert rest_frames(X, tracked, npts, None, 0.02, tree, 50, 0.02, 5.0, 0.01, 40) == []
    X2 = X.copy()
    X2[3] = _yaw(8.0, (0.3, 0.0, 0.05))  # the object turned: the rest ends there
    assert rest_frames(X2, tracked, npts, p, 0.02, tree, 50, 0.02, 5.0, 0.01, 40) == [1, 2]


def test_gauge_config_validation():
    with pytest.raises(ValueError):
        TrackingConfig(gauge_frames=-1)
    with pytest.raises(ValueError):
        TrackingConfig(gauge_ee_margin=-1.0)
