"""The cap of the spin correction raised by the roll of a lying body of revolution that the tracked poses do not show
(``spin_cap_roll``, ``lying.unseen_roll``, ``tracker._spin_cap``)."""
import numpy as np
import pytest

from service.tracking import TrackingConfig
from service.tracking.lying import lying_geometry, unseen_roll
from service.tracking.tracker import _spin_cap
from service.transforms import so3_exp
from tests.tracking.test_lying import TABLE, _bottle  # the same bottle model


def _rolling(Q, roll_deg, seen):
    """80 frames: 20 standing on the base (frame 0 identity), then lying along x on the table, rolling without slip by
    ``roll_deg`` about its axis over frames 35-65 (the axis point moves r·φ across the axis). ``seen``: the poses turn
    with the roll (the truth); otherwise they keep the turn of the landing (a tracker that misses the roll) while their
    positions follow it. Poses (N,4,4)."""
    a, p_O, r = lying_geometry(Q, np.array([0.0, 0.0, 1.0]))
    X = np.tile(np.eye(4), (80, 1, 1))
    X[:20, 2, 3] = TABLE - Q[:, 2].min()
    phi = np.radians(roll_deg) * np.clip((np.arange(80) - 35) / 30.0, 0.0, 1.0)
    R_lie = so3_exp(np.array([0.0, np.pi / 2, 0.0]))  # ẑ_O along x of W
    for i in range(20, 80):
        R = R_lie @ so3_exp(np.array([0.0, 0.0, phi[i] if seen else 0.0]))
        P = np.array([0.0, -r * phi[i], TABLE + r])  # v_P = ω r (a × ẑ), a × ẑ = −ŷ
        X[i, :3, :3] = R
        X[i, :3, 3] = P - R @ p_O
    return X


def test_unseen_roll_measures_what_the_poses_miss():
    rng = np.random.default_rng(3)
    Q = _bottle(rng)
    up = np.array([0.02, 0.01, 1.0])
    missed = np.degrees(unseen_roll(_rolling(Q, 100.0, seen=False), Q, TABLE, up))
    assert abs(missed - 100.0) < 3.0  # the model's radius within 1 mm of the true one
    assert np.degrees(unseen_roll(_rolling(Q, 100.0, seen=True), Q, TABLE, up)) < 1.0
    assert np.degrees(unseen_roll(_rolling(Q, -60.0, seen=False), Q, TABLE, up)) == pytest.approx(60.0, abs=2.0)


def test_no_roll_measured_without_the_geometry():
    rng = np.random.default_rng(4)
    Q = _bottle(rng)
    X = _rolling(Q, 100.0, seen=False)
    assert unseen_roll(X, Q, TABLE, np.array([1.0, 0.0, 0.3])) == 0.0  # did not stand on its base at frame 0
    assert unseen_roll(X, Q, TABLE - 0.05, np.array([0.0, 0.0, 1.0])) == 0.0  # not on the table
    assert unseen_roll(X[:20], Q, TABLE, np.array([0.0, 0.0, 1.0])) == 0.0  # never lying
    E = _bottle(rng, egg=True)
    assert unseen_roll(X, E, TABLE, np.array([0.0, 0.0, 1.0])) == 0.0  # no straight stretch


class _Model:
    def __init__(self, Q):
        self.Q = Q


def test_cap_raised_only_with_the_option():
    rng = np.random.default_rng(5)
    Q = _bottle(rng)
    X = _rolling(Q, 100.0, seen=False)
    axis = (True, 0.01, np.array([0.0, 0.0, 1.0]), np.zeros(3))
    assert _spin_cap(X, _Model(Q), axis, TABLE, TrackingConfig()) == 120.0  # off (default): spin_max_deg itself
    on = TrackingConfig(spin_cap_roll=True)
    assert _spin_cap(X, _Model(Q), axis, TABLE, on) == pytest.approx(220.0, abs=3.0)
    assert _spin_cap(X, _Model(Q), (False,) + axis[1:], TABLE, on) == 120.0  # not a body of revolution
    assert _spin_cap(X, _Model(Q), axis, None, on) == 120.0  # table height unknown
    assert _spin_cap(X, _Model(Q), axis, TABLE, TrackingConfig(spin_cap_roll=True, spin_max_deg=0.0)) == 0.0  # no cap


def test_bad_setting_refused():
    with pytest.raises(ValueError):
        TrackingConfig(spin_cap_roll=1)
