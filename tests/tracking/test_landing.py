"""Starts for toppling landings and the table as a test of a pose (service.tracking.landing)."""

import numpy as np

from service.tracking.landing import below_table_frac, land_on_table, pose_consistent, screw_path, screw_power
from service.transforms import make_X, rotation_angle, se3_exp, se3_log, so3_exp


def _box_surface(h, n=3000, seed=0):
    rng = np.random.default_rng(seed)
    P = rng.uniform(-h, h, (n, 3))
    ax = rng.integers(0, 3, n)
    P[np.arange(n), ax] = np.where(rng.random(n) < 0.5, -1, 1) * h[ax]
    return P


def _tipped(theta_deg, h):
    """Pose of a box (half extents h) standing on the table z = 0, turned by theta about its bottom edge
    y = +h_y, z = 0 (a topple toward +y)."""
    edge = np.array([0.0, h[1], 0.0])
    R = so3_exp(np.radians([-theta_deg, 0.0, 0.0]))
    c0 = np.array([0.0, 0.0, h[2]])  # centre of the standing box
    return make_X(R, edge + R @ (c0 - edge))


def test_se3_log_exp_roundtrip_and_power():
    X = make_X(so3_exp(np.array([0.3, -0.2, 0.5])), np.array([0.1, -0.05, 0.2]))
    w, u = se3_log(X)
    assert np.allclose(se3_exp(w, u), X, atol=1e-10)
    assert np.allclose(screw_power(X, 2.0), X @ X, atol=1e-10)
    assert np.allclose(screw_power(X, 0.5) @ screw_power(X, 0.5), X, atol=1e-10)


def test_landing_pose_of_a_topple_is_flat_on_the_table():
    h = np.array([0.035, 0.035, 0.1])  # a carton 7 x 7 x 20 cm
    Q = _box_surface(h)
    X_b, X_a = _tipped(60.0, h), _tipped(75.0, h)  # 15° per frame, the landing due within two frames
    assert below_table_frac(X_a, Q, 0.0, 0.002) == 0.0
    # the constant-velocity prediction (k = 2: 105°) goes through the table
    assert below_table_frac(screw_path(X_b, X_a, [2])[0], Q, 0.0, 0.002) > 0.05
    X_land = land_on_table(X_b, X_a, Q, 0.0, k_max=2.0)
    assert X_land is not None
    err = np.degrees(rotation_angle(X_land[:3, :3].T @ _tipped(90.0, h)[:3, :3]))
    assert err < 1.0
    assert np.linalg.norm(X_land[:3, 3] - _tipped(90.0, h)[:3, 3]) < 0.003
    # no fall: a slow step is not continued, and the model already on the table gives no landing
    assert land_on_table(_tipped(74.0, h), X_a, Q, 0.0, k_max=2.0) is None
    assert land_on_table(_tipped(75.0, h), _tipped(90.0, h), Q, 0.0, k_max=2.0) is None


def test_pose_consistent_rejects_a_pose_through_the_table():
    h = np.array([0.035, 0.035, 0.1])
    Q = _box_surface(h)
    assert pose_consistent(_tipped(90.0, h), Q, 0.0, None, 0.01, 0.02, 0.05)
    assert not pose_consistent(_tipped(110.0, h), Q, 0.0, None, 0.01, 0.02, 0.05)
