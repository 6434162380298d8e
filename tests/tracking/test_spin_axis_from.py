"""The spin closure's axis from data the loop's swing did not smear (spin_axis_from, service/tracking/spinaxis.py,
tracker._closure_axis)."""

import numpy as np
import pytest

import service.tracking.tracker as T
from service.tracking import spinaxis as SA
from service.tracking.spin import find_axis
from service.tracking.types import TrackingConfig
from service.transforms import make_X, so3_exp

from .test_spin import _egg_model


def _deg(a, b):
    return float(np.degrees(np.arccos(min(abs(float(a @ b)), 1.0))))


def _rolling(a_O, n=200, rng=None):
    """Poses X_WO (n,4,4) of a body lying with its axis a_O (in O) horizontal (along x̂_W) and rolling about it."""
    rng = rng or np.random.default_rng(1)
    v = np.cross(a_O, [1.0, 0.0, 0.0])
    R0 = so3_exp(v / np.linalg.norm(v) * np.arcsin(min(np.linalg.norm(v), 1.0)))
    if R0 @ a_O @ [1.0, 0.0, 0.0] < 0:
        R0 = so3_exp(np.array([0.0, 0.0, np.pi])) @ R0
    th = np.cumsum(rng.uniform(0.0, 0.03, n))  # a slow roll (below spin.fast_frames' rate), 3 rad in all
    return np.stack([make_X(so3_exp(np.array([t, 0.0, 0.0])) @ R0, np.array([0.0, -0.03 * t, 0.03])) for t in th])


def test_still_frames():
    rng = np.random.default_rng(0)
    X = np.stack([np.eye(4)] * 20)
    for i in range(1, 12):  # at rest: a few degrees of noise in the weak rotations, < 1 mm
        X[i, :3, :3] = so3_exp(np.radians(4.0) * rng.normal(size=3) / np.sqrt(3))
        X[i, :3, 3] = 0.0005 * rng.normal(size=3)
    for i in range(12, 20):  # then the body rolls away
        X[i, :3, 3] = [0.01 * (i - 11), 0.0, 0.0]
    assert list(SA.still_frames(X)) == list(range(12))
    X[5, :3, :3] = so3_exp(np.radians([0.0, 0.0, 12.0]))  # a turn above STILL_DEG ends the still stretch
    assert list(SA.still_frames(X)) == list(range(5))


def test_still_axis_of_a_seen_side():
    Q, N, axis, ctr = _egg_model()
    a0 = so3_exp(np.cross(axis, [0.0, 0.0, 1.0]) * 0.5) @ axis  # a start ~25° off, as a smeared model's axis
    a, c, rms = SA.still_axis(Q, N, a0, ctr + 0.005)
    assert _deg(a, axis) < 2.0 and rms < 0.002
    assert np.linalg.norm(np.cross(c - ctr, axis)) < 1e-3  # c on the axis


def test_lying_axis():
    a_O = np.array([0.3, -0.5, 0.8])
    a_O /= np.linalg.norm(a_O)
    X = _rolling(a_O)
    assert np.allclose(np.abs(np.einsum("nij,j->ni", X[:, :3, :3], a_O)[:, 2]), 0.0, atol=1e-9)  # horizontal
    a0 = so3_exp(np.array([0.15, 0.1, 0.0])) @ a_O  # the smeared model's axis, ~10° off
    a, n = SA.lying_axis(X, a0)
    assert n == len(X) and _deg(a, a_O) < 0.1 and a @ a0 > 0
    a, n = SA.lying_axis(X[:8], a0)  # too few lying frames: the model's axis kept
    assert n == 8 and np.array_equal(a, a0)


def test_profile_point_keeps_direction():
    Q, N, axis, ctr = _egg_model()
    c = SA.profile_point(Q, axis, ctr + np.array([0.004, -0.003, 0.002]))
    assert np.linalg.norm(np.cross(c - ctr, axis)) < 1e-3


def _axis(model, cfg, tau=0.05):
    """``spin.find_axis``'s result on the model, as the closure fits it."""
    return find_axis(model.Q, model.N, tau, cfg.spin_sep, cfg.spin_profile)


def test_closure_axis_replaces_the_direction(monkeypatch):
    Q, N, axis, ctr = _egg_model()
    model = T.ObjectModel(0.002, Q, N, None)
    seen = {}

    def fake(obs, X, model_, cfg, a0, c0):
        seen["a0"] = a0
        return axis, ctr

    monkeypatch.setitem(T._AXIS_FROM, "still", fake)
    cfg = TrackingConfig(spin_axis_from="still")
    ok, lam, a, c = T._closure_axis([], np.stack([np.eye(4)]), model, cfg, _axis(model, cfg))
    assert ok and np.array_equal(a, axis) and np.array_equal(c, ctr) and "a0" in seen
    few = T.ObjectModel(0.002, Q[:10], N[:10], None)
    ok, *_ = T._closure_axis([], np.stack([np.eye(4)]), few, cfg, _axis(few, cfg))
    assert not ok  # no body of revolution: the candidate is not asked


def test_config():
    assert TrackingConfig().spin_axis_from == "model"  # off by default: the final model's axis
    for v in ("still", "lying"):
        TrackingConfig(spin_axis_from=v)
    for v in ("frames", "", None, 1):
        with pytest.raises(ValueError):
            TrackingConfig(spin_axis_from=v)
