"""More rounds of the closures of egg-like bodies (tracker._spin_rounds, TrackingConfig.spin_rounds) with the
closures replaced by stubs: which round is kept, what the keyframes and the model become."""

from dataclasses import replace

import numpy as np
import pytest

import service.tracking.tracker as T
from service.tracking.spin import SpinResult
from service.tracking.types import TrackingConfig
from service.transforms import make_X, so3_exp

N = 6


def _spin(theta_deg: float, rev: bool = True) -> SpinResult:
    th = np.full(N, np.radians(theta_deg))
    th[0] = 0.0
    return SpinResult(rev, 0.01, np.array([1.0, 0.0, 0.0]), np.zeros(3), th, np.full(N, 20), True)


def _setup(rng):
    """Poses (N,4,4) turning about z, two keyframes (frames 0 and 3) whose poses are 5° off the poses X (the loop's
    rotations), and the model built from them."""
    X = np.stack([make_X(so3_exp(np.array([0.0, 0.0, 0.1 * i])), np.array([0.5, 0.0, 0.04])) for i in range(N)])
    kfs = []
    for i in (0, 3):
        P_W = rng.normal(scale=0.03, size=(200, 3)) + X[i, :3, 3]
        N_W = rng.normal(size=(200, 3))
        N_W /= np.linalg.norm(N_W, axis=1, keepdims=True)
        Xk = X[i] if i == 0 else X[i] @ make_X(so3_exp(np.array([np.radians(5), 0.0, 0.0])), np.zeros(3))
        kf = T.Keyframe(i, Xk.copy(), np.zeros((0, 3)), P_W, N_W, np.zeros((0, 3)), None, np.zeros((0, 3)))
        T._place_keyframe(kf, Xk.copy(), None)
        kfs.append(kf)
    return X, kfs, T._model_from(kfs, 0.004)


@pytest.fixture
def stubs(monkeypatch):
    """The closures stubbed: the spin closure turns every frame by the next queued θ about x and returns it."""
    queue: list[SpinResult] = []
    seen_models: list = []

    def spin_closure(obs, X, model, cfg):
        res = queue.pop(0)
        seen_models.append(model)
        for i, t in enumerate(res.theta):
            X[i] = X[i] @ make_X(so3_exp(np.array([t, 0.0, 0.0])), np.zeros(3))
        return res

    monkeypatch.setattr(T, "_spin_closure", spin_closure)
    monkeypatch.setattr(T, "_spin_tilt", lambda *a, **k: None)
    monkeypatch.setattr(T, "_level_lying", lambda *a, **k: None)
    monkeypatch.setattr("service.tracking.spin.revolution_axis", lambda *a, **k: (False, 0.01, None, None))
    return queue, seen_models


def test_round_kept_when_small(stubs):
    queue, seen = stubs
    X, kfs, model = _setup(np.random.default_rng(0))
    X0 = X.copy()
    queue.append(_spin(2.0))
    cfg = replace(TrackingConfig(), spin_rounds=1)
    spin, tilt, m2 = T._spin_rounds([], X, model, kfs, None, _spin(10.0), None, 0.0, cfg)
    # the round ran on the model rebuilt from the keyframes at the corrected poses (keyframe 3 moved by 5°)
    assert np.allclose(kfs[1].X_WO, X0[3])
    assert seen[0] is m2 and not np.array_equal(m2.Q, model.Q)
    # its correction applied to X and its result returned
    assert np.allclose(X[3], X0[3] @ make_X(so3_exp(np.array([np.radians(2.0), 0.0, 0.0])), np.zeros(3)))
    assert np.isclose(spin.theta[3], np.radians(2.0))


def test_round_undone_when_large(stubs):
    queue, _ = stubs
    X, kfs, model = _setup(np.random.default_rng(1))
    X0, K0 = X.copy(), [kf.X_WO.copy() for kf in kfs]
    P0 = [kf.P_O.copy() for kf in kfs]
    first = _spin(10.0)
    queue.extend([_spin(6.0), _spin(1.0)])  # the first round over the 5° cap: it and the second are not kept
    cfg = replace(TrackingConfig(), spin_rounds=2, spin_rounds_max_deg=5.0)
    spin, tilt, m2 = T._spin_rounds([], X, model, kfs, None, first, None, 0.0, cfg)
    assert spin is first and m2 is model and np.array_equal(X, X0)
    assert all(np.array_equal(kf.X_WO, k0) for kf, k0 in zip(kfs, K0))
    assert all(np.allclose(kf.P_O, p0) for kf, p0 in zip(kfs, P0))
    assert len(queue) == 1  # the rounds stopped


def test_not_egg_left_alone(stubs, monkeypatch):
    queue, _ = stubs
    X, kfs, model = _setup(np.random.default_rng(2))
    X0 = X.copy()
    cfg = replace(TrackingConfig(), spin_rounds=1)
    for first in (_spin(10.0, rev=False), None):  # no body of revolution, no spin closure
        out = T._spin_rounds([], X, model, kfs, None, first, None, 0.0, cfg)
        assert out[0] is first and out[2] is model
    monkeypatch.setattr("service.tracking.spin.revolution_axis", lambda *a, **k: (True, 0.01, None, None))
    out = T._spin_rounds([], X, model, kfs, None, _spin(10.0), None, 0.0, cfg)  # a bottle: one weakest rotation
    assert out[2] is model and np.array_equal(X, X0) and not queue


def test_config():
    assert TrackingConfig().spin_rounds == 0 and TrackingConfig().spin_rounds_max_deg == 5.0
    for bad in (dict(spin_rounds=-1), dict(spin_rounds=1.5), dict(spin_rounds_max_deg=0.0)):
        with pytest.raises(ValueError):
            TrackingConfig(**bad)
