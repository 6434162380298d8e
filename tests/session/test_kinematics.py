"""Panda forward kinematics (pybullet URDF) against an independent numpy implementation of the
published modified-DH parameters, and through ingest with robot.joints = franka_panda."""

from __future__ import annotations

import numpy as np
import pytest

from service.session import ingest
from service.session.kinematics import panda_flange_poses, panda_sphere_centres
from tests.session.conftest import Spec, write_session

# Franka Emika Panda, Craig's (modified) DH: (a_{i-1}, d_i, alpha_{i-1}) for joints 1..7 and the flange.
DH = [
    (0.0, 0.333, 0.0),
    (0.0, 0.0, -np.pi / 2),
    (0.0, 0.316, np.pi / 2),
    (0.0825, 0.0, np.pi / 2),
    (-0.0825, 0.384, -np.pi / 2),
    (0.0, 0.0, np.pi / 2),
    (0.088, 0.0, np.pi / 2),
    (0.0, 0.107, 0.0),  # flange, theta = 0
]


def dh_flange(q: np.ndarray) -> np.ndarray:
    """X_WF (4,4) from the modified DH chain: T = RotX(alpha) TransX(a) RotZ(theta) TransZ(d)."""
    X = np.eye(4)
    for (a, d, alpha), th in zip(DH, list(q) + [0.0]):
        ca, sa, ct, st = np.cos(alpha), np.sin(alpha), np.cos(th), np.sin(th)
        T = np.array(
            [
                [ct, -st, 0, a],
                [st * ca, ct * ca, -sa, -d * sa],
                [st * sa, ct * sa, ca, d * ca],
                [0, 0, 0, 1],
            ]
        )
        X = X @ T
    return X


def test_zero_configuration_known_flange_pose():
    X = panda_flange_poses(np.zeros((1, 7)))[0]
    np.testing.assert_allclose(X[:3, 3], [0.088, 0.0, 0.333 + 0.316 + 0.384 - 0.107], atol=1e-6)
    np.testing.assert_allclose(X[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-6)
    np.testing.assert_allclose(dh_flange(np.zeros(7)), X, atol=1e-6)


def test_random_configurations_match_dh():
    rng = np.random.default_rng(3)
    lo = np.array([-2.9, -1.76, -2.9, -3.07, -2.9, -0.02, -2.9])
    hi = np.array([2.9, 1.76, 2.9, -0.07, 2.9, 3.75, 2.9])
    q = rng.uniform(lo, hi, size=(20, 7))
    X = panda_flange_poses(q)
    for k in range(len(q)):
        np.testing.assert_allclose(X[k], dh_flange(q[k]), atol=1e-6)


def test_default_tip_is_0_2335_from_link7():
    q = np.array([[0.1, -0.4, 0.2, -2.0, 0.1, 1.7, 0.6]])
    p = panda_sphere_centres(q, np.array([0.0, 0.0, 0.1265]))[0]
    X = dh_flange(q[0])
    link7_origin = X[:3, 3] - X[:3, 2] * 0.107
    assert np.linalg.norm(p - link7_origin) == pytest.approx(0.2335, abs=1e-6)
    np.testing.assert_allclose(p, link7_origin + X[:3, 2] * 0.2335, atol=1e-6)


def test_ingest_with_joint_angles(tmp_path):
    rng = np.random.default_rng(0)
    n, fps = 4, 10.0
    t = np.linspace(-0.05, 0.35, 9)
    q0 = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8])
    q = q0 + 0.05 * rng.standard_normal((len(t), 7)) * np.linspace(0, 1, len(t))[:, None]
    rows = [["t"] + [f"q{i}" for i in range(1, 8)]] + [[ti] + list(qi) for ti, qi in zip(t, q)]
    offset = [0.0, 0.01, 0.12]
    src = write_session(
        tmp_path / "src",
        Spec(n=n, fps=fps, robot_rows=rows, meta={"robot": {"joints": "franka_panda", "tip_offset": offset}}),
    )
    s = ingest(src, tmp_path / "d")
    expect = np.array([(dh_flange(qi) @ np.r_[offset, 1.0])[:3] for qi in q])
    np.testing.assert_allclose(s.robot_p_WE, expect, atol=1e-6)
    frame_t = np.arange(n) / fps
    interp = np.stack([np.interp(frame_t, t, expect[:, d]) for d in range(3)], axis=1)
    np.testing.assert_allclose(s.p_WE, interp, atol=1e-6)
    assert s.cmd_WE is None and s.robot_cmd_WE is None
