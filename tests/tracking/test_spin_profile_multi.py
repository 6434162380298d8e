"""The radius-profile refit of an egg's axis started from every rotation eigen-axis (spin_profile "multi",
service/tracking/spin.py: find_axis, profile_starts)."""

import numpy as np
import pytest

import service.tracking.spin as S
from service.tracking.types import TrackingConfig

from .test_spin import _egg_model


def _deg(a, b):
    return float(np.degrees(np.arccos(min(abs(float(a @ b)), 1.0))))


def _across(monkeypatch, Q, axis, ctr):
    """Make the weakest eigen-axis (the single start of "mixed") lie across the egg, 10 mm off its centre, as the
    mixed weak rotations of a development egg's model did."""
    e1 = np.cross(axis, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    real = S.revolution_axis

    def across(Q_, N_, tau, sep=0.5, k=0):
        ok, lam, _, _ = real(Q_, N_, tau, 1.0, k)
        return (ok and sep >= 1.0), lam, e1, ctr + 0.01 * np.cross(axis, e1)

    monkeypatch.setattr(S, "revolution_axis", across)


def test_stuck_refit_recovered(monkeypatch):
    Q, N, axis, ctr = _egg_model()
    _across(monkeypatch, Q, axis, ctr)
    ok, _, a, c = S.find_axis(Q, N, 0.05, 0.5, "mixed")
    assert ok and _deg(a, axis) > 60.0  # one start: the profile refit stays across the body (a local minimum)
    ok, _, a, c = S.find_axis(Q, N, 0.05, 0.5, "multi")
    assert ok and _deg(a, axis) < 2.0  # the best of the starts is the long axis
    assert np.linalg.norm(np.cross(c - ctr, axis)) < 1e-3  # c on the axis


def test_multi_keeps_a_good_axis():
    Q, N, axis, ctr = _egg_model()
    r_mixed = S.find_axis(Q, N, 0.05, 0.5, "mixed")
    r_multi = S.find_axis(Q, N, 0.05, 0.5, "multi")
    assert r_multi[0] and _deg(r_multi[2], axis) < 2.0 and _deg(r_multi[2], r_mixed[2]) < 1.0


def test_profile_starts():
    Q, N, axis, ctr = _egg_model()
    st = S.profile_starts(Q, N)
    assert len(st) == 6  # three rotations, each at its screw point and at the centroid
    for a, c in st:
        assert abs(np.linalg.norm(a) - 1.0) < 1e-9
    assert any(np.allclose(c, Q.mean(0)) for _, c in st)
    assert min(_deg(a, axis) for a, _ in st) < 15.0


def test_config():
    assert TrackingConfig().spin_profile == "multi"  # on by default (docs/tracking.md, step 13)
    TrackingConfig(spin_profile="mixed")
    with pytest.raises(ValueError):
        TrackingConfig(spin_profile="best")
