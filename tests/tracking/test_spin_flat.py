"""Flat faces are not a surface of revolution (service.tracking.spin.flat_faced, TrackingConfig.spin_flat_kappa): a
long square prism seen on three sides passes the λ̂ test of a body of revolution (its side faces' residual under the
spin about its long axis is small against its length) and is refused by the meridian test; bottles seen whole or in
part and an egg seen from one side, with normals as noisy as the tracker's merged models, are kept; off (0) changes
nothing."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from service.tracking import TrackingConfig
from service.tracking.spin import arc_score, find_axis, flat_faced, partial_tau, revolution_axis
from service.tracking.tracker import _flat_faced, _spin_closure, _spin_tau
from service.transforms import make_X, so3_exp

from tests.tracking.test_spin import _egg_model
from tests.tracking.test_spin_partial import _bottle

KAPPA = 0.12  # the threshold the tests use (docs/tracking-findings.md "Boxes are not bodies of revolution")


def _prism(seed: int = 0, n: int = 3000, noise_deg: float = 20.0, ext=(0.30, 0.06, 0.06)):
    """Points (n,3) and unit normals of the faces −y, +z and +x (an end) of a box of extents ``ext`` (long axis x),
    normals perturbed by about ``noise_deg``, placed anywhere in O."""
    rng = np.random.default_rng(seed)
    e = np.array(ext) / 2
    P, N = [], []
    for ax, s, k in ((1, -1, 0.45), (2, 1, 0.45), (0, 1, 0.10)):
        m = int(k * n)
        p = rng.uniform(-e, e, (m, 3))
        p[:, ax] = s * e[ax]
        q = np.zeros((m, 3))
        q[:, ax] = s
        P.append(p)
        N.append(q)
    P = np.vstack(P)
    N = np.vstack(N) + rng.normal(0, np.radians(noise_deg) / np.sqrt(2), P.shape)
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    X = make_X(so3_exp(np.array([0.4, -0.3, 0.2])), np.array([0.02, 0.01, -0.05]))
    return P @ X[:3, :3].T + X[:3, 3], N @ X[:3, :3].T, X[:3, 0]


def _axis(Q, N, tau=0.03, sep=0.5):
    return find_axis(Q, N, partial_tau(Q, N, tau, sep, 0.08), sep, "multi")


def test_long_prism_passes_the_lambda_test_and_is_refused():
    Q, N, long_axis = _prism()
    axis = _axis(Q, N)
    assert axis[0] and axis[1] < 0.03  # taken for a body of revolution by the λ̂ test ...
    assert abs(axis[2] @ long_axis) > np.cos(np.radians(10))  # ... about its long axis
    assert arc_score(Q, N, axis[2], axis[3]) > 0.15  # flat faces: κ ≈ 1/4 on the sides, diluted by the end
    assert flat_faced(Q, N, axis, KAPPA)
    assert not flat_faced(Q, N, axis, 0.0)  # off


@pytest.mark.parametrize("h0, h1", [(0.0, 0.2), (0.045, 0.13)])
def test_bottles_kept(h0, h1):
    Q, N = _bottle(h0, h1)
    axis = _axis(Q, N)
    assert axis[0]
    assert arc_score(Q, N, axis[2], axis[3]) < 0.08
    assert not flat_faced(Q, N, axis, KAPPA)


def test_egg_kept():
    Q, N, _, _ = _egg_model()
    axis = find_axis(Q, N, 0.05, 0.5, "multi")
    assert axis[0]
    assert not flat_faced(Q, N, axis, KAPPA)


def test_model_not_taken_for_a_body_of_revolution_is_not_scored():
    P = np.random.default_rng(1).uniform(-1, 1, (300, 3)) * [0.05, 0.03, 0.02]
    Nb = np.tile([0.0, 0.0, 1.0], (300, 1))
    axis = (False, 0.2, np.zeros(3), np.zeros(3))
    assert not flat_faced(P, Nb, axis, KAPPA)


def _tracker_axis(model, cfg):
    """The axis test's result as the tracker fits it."""
    return find_axis(model.Q, model.N, _spin_tau(model, cfg), cfg.spin_sep, cfg.spin_profile)


def test_tracker_leaves_a_prism_alone_only_when_on():
    Q, N, _ = _prism()
    model = SimpleNamespace(Q=Q, N=N)
    n = 5
    on = TrackingConfig(spin_flat_kappa=KAPPA)
    res = _flat_faced(model, on, _tracker_axis(model, on), n)
    assert res is not None and not res.is_revolution and not res.observable
    assert res.theta.shape == (n,) and not res.theta.any() and not res.axis_O.any()
    obs = [SimpleNamespace(spin_feats=None, P_W=np.zeros((0, 3))) for _ in range(n)]
    X = np.tile(np.eye(4), (n, 1, 1))
    X0 = X.copy()
    assert not _spin_closure(obs, X, model, on).is_revolution
    assert np.array_equal(X, X0)
    assert _spin_closure(obs, X, model, TrackingConfig(spin_flat_kappa=0.0)).is_revolution  # off: taken for one
    Qb, Nb = _bottle(0.0, 0.2)
    bottle = SimpleNamespace(Q=Qb, N=Nb)
    assert _flat_faced(bottle, on, _tracker_axis(bottle, on), n) is None  # a bottle proceeds


def test_config_validates_flat_kappa():
    assert TrackingConfig().spin_flat_kappa == KAPPA  # on by default
    for bad in (-0.1, 1.0):
        with pytest.raises(ValueError):
            TrackingConfig(spin_flat_kappa=bad)
