"""A short open cup taken for a body of revolution by the κ separation (service.tracking.spin.kappa_sep_axis,
TrackingConfig.spin_sep_kappa): a 40 mm band of a cup's outer and inner walls with its rim, normals as noisy as the
tracker's merged models, fails the λ̂ and separation tests (its tilts nearly as weak as its spin) and is accepted
with its axis; a box seen on three sides, a near-sphere and the option off are refused; the tracker's closure takes
the cup only with the option on and skips the tilt closure for it."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from service.tracking import TrackingConfig
from service.tracking.spin import find_axis, kappa_sep_axis, partial_tau
from service.tracking.tracker import _spin_closure, _spin_tilt

from tests.tracking.test_spin_flat import _prism

RATIO, ARC = 2.0, 0.08


def _cup(seed: int = 0, n: int = 1400, noise_deg: float = 20.0, band: float = 0.04, rim: float = 0.06):
    """Points (n,3) and unit normals in O of a cup (outer radius 42.5 mm, wall 6 mm, axis +z): the outer wall over
    azimuths −140…75°, the inner wall across the mouth (the opposite azimuths), both over a ``band`` of height, and a
    ``rim`` fraction of the points on the rim annulus; normals perturbed by about ``noise_deg``."""
    rng = np.random.default_rng(seed)
    R, ri = 0.0425, 0.0365
    nr = int(n * rim)
    nw = n - nr
    m = nw // 2
    phi = np.radians(rng.uniform(-140, 75, m))
    z = rng.uniform(0, band, m)
    P = [np.c_[R * np.cos(phi), R * np.sin(phi), z]]
    N = [np.c_[np.cos(phi), np.sin(phi), 0 * z]]
    phi = np.radians(rng.uniform(40, 255, nw - m))
    z = rng.uniform(0, band, nw - m)
    P.append(np.c_[ri * np.cos(phi), ri * np.sin(phi), z])
    N.append(np.c_[-np.cos(phi), -np.sin(phi), 0 * z])
    phi = rng.uniform(0, 2 * np.pi, nr)
    r = rng.uniform(ri, R, nr)
    P.append(np.c_[r * np.cos(phi), r * np.sin(phi), np.full(nr, band)])
    N.append(np.tile([0.0, 0.0, 1.0], (nr, 1)))
    P = np.vstack(P)
    N = np.vstack(N) + rng.normal(0, np.radians(noise_deg) / np.sqrt(2), (n, 3))
    return P, N / np.linalg.norm(N, axis=1, keepdims=True)


def _default_axis(Q, N):
    return find_axis(Q, N, partial_tau(Q, N, 0.03, 0.5, ARC), 0.5, "multi")


def test_cup_refused_by_default_and_taken_by_kappa():
    Q, N = _cup()
    assert not _default_axis(Q, N)[0]  # λ̂₁ above spin_tau and not separated from the tilt by λ̂
    ok, lam, a, c = kappa_sep_axis(Q, N, RATIO, ARC)
    assert ok and lam > 0.03
    assert abs(a[2]) > np.cos(np.radians(5))  # about the cup's axis
    assert np.hypot(*c[:2]) < 0.005  # the axis line through the cup's centre
    assert not kappa_sep_axis(Q, N, 0.0, ARC)[0]  # off
    assert not kappa_sep_axis(Q, N, RATIO, 0.0)[0]  # no arc threshold: off
    assert not kappa_sep_axis(Q, N, 10.0, ARC)[0]  # the tilt's κ is not ten times the spin's


def test_box_and_near_sphere_refused():
    Q, N, _ = _prism(ext=(0.20, 0.07, 0.07))
    assert not kappa_sep_axis(Q, N, RATIO, ARC)[0]
    rng = np.random.default_rng(3)  # a sphere seen on one side: every rotation about its centre is free
    d = rng.normal(size=(1500, 3))
    d[:, 0] = np.abs(d[:, 0])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    Ns = d + rng.normal(0, np.radians(10) / np.sqrt(2), d.shape)
    assert not kappa_sep_axis(0.04 * d, Ns / np.linalg.norm(Ns, axis=1, keepdims=True), RATIO, ARC)[0]


def test_tracker_closure_takes_the_cup_only_when_on(monkeypatch):
    Q, N = _cup()
    model = SimpleNamespace(Q=Q, N=N)
    n = 5
    obs = [SimpleNamespace(spin_feats=None, P_W=np.zeros((0, 3))) for _ in range(n)]
    X = np.tile(np.eye(4), (n, 1, 1))
    off = _spin_closure(obs, X, model, TrackingConfig())
    assert not off.is_revolution and not off.by_kappa
    on_cfg = TrackingConfig(spin_sep_kappa=RATIO)
    on = _spin_closure(obs, X, model, on_cfg)
    assert on.is_revolution and on.by_kappa and abs(on.axis_O[2]) > np.cos(np.radians(5))
    assert np.array_equal(X, np.tile(np.eye(4), (n, 1, 1)))  # no texture: θ = 0, poses unchanged
    from dataclasses import replace

    import service.tracking.tilt as tilt

    calls = []
    monkeypatch.setattr(tilt, "prolate", lambda *a: True)  # as if the cup were taller than wide
    monkeypatch.setattr(tilt, "tilt_closure", lambda *a, **k: calls.append(1) or None)
    monkeypatch.setattr(tilt, "apply_tilt", lambda X, res: X)
    assert _spin_tilt(obs, X, model, replace(on, observable=True), on_cfg) is None  # no tilt closure on a cup
    assert not calls
    _spin_tilt(obs, X, model, replace(on, observable=True, by_kappa=False), on_cfg)  # an egg-like body: it runs
    assert calls


def test_config_validates_sep_kappa():
    assert TrackingConfig().spin_sep_kappa == 0.0  # off by default
    assert TrackingConfig(spin_sep_kappa=2.0).spin_sep_kappa == 2.0
    for bad in (-1.0, float("nan"), float("inf"), True):
        with pytest.raises(ValueError):
            TrackingConfig(spin_sep_kappa=bad)
