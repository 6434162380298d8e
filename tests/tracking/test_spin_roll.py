"""Rolling constraint (service.tracking.spin ``roll_spin``, ``spin_roll``): a cylinder lying on the table rolls 60°
without slipping while the tracked poses keep only half of that spin and the texture (constructed matches) sees only
40 % of what the tracker misses; the chain then ends 18° off, the roll taken from the tracked translation over the
contact radius recovers the spin within 1.5° in every frame. A texture that sees 90 % of the roll is kept. A cylinder that slides the same distance without turning
is left to the texture (the guard refuses the roll), and without the guard the roll would turn it by 60°."""

from __future__ import annotations

import numpy as np
import pytest

from service.tracking.spin import find_axis, roll_spin, spin_closure, spin_matrix, spin_mixed
from service.tracking.types import TrackingConfig
from service.transforms import make_X
from tests.tracking.cylinder_feats import cylinder_features
from tests.tracking.test_spin import R_CYL, _cylinder_model

ROLL = range(20, 40)  # 3° per frame about the axis, from frame 20 to 39 (60° in all)


def _scene(rolls: bool = True, seen: float = 0.4):
    """Model (Q, N) in O (axis along x_O at height R, W = O at frame 0: lying on the table z = 0), tracked poses,
    the correction the spin needs, and features whose matches see the fraction ``seen`` of that correction."""
    Q, N = _cylinder_model()
    ok, _, a, c = find_axis(Q, N, 0.02, 0.5, "off")
    assert ok
    n = 60
    beta = np.radians(3.0) * np.clip(np.arange(n) - ROLL.start + 1, 0, len(ROLL))  # spin about x_W (rad)
    y = -R_CYL * beta  # rolling without slipping: turning by β about +x moves the axis by −R β along y
    if not rolls:
        beta = np.zeros(n)  # slides the same distance without turning
    sgn = float(np.sign(a[0]))
    X_true = np.stack([make_X(np.eye(3), np.array([0.0, yy, 0.0])) @ spin_matrix(a, c, sgn * b) for yy, b in zip(y, beta)])
    X_trk = np.stack([make_X(np.eye(3), np.array([0.0, yy, 0.0])) @ spin_matrix(a, c, sgn * b / 2) for yy, b in zip(y, beta)])
    err = sgn * beta / 2  # X_trk S(err) = X_true
    X_seen = np.stack([X @ spin_matrix(a, c, seen * e) for X, e in zip(X_trk, err)])  # what the texture follows
    e1 = np.array([0.0, 1.0, 0.0])
    feats = cylinder_features(a, c, e1, X_seen)
    return Q, N, X_trk, err, feats


def _match(da: np.ndarray, db: np.ndarray) -> np.ndarray:
    """30 matches by point id between frames at most 12 apart (byte 2: the frame), none otherwise."""
    i, j = int(da[0, 2]), int(db[0, 2])
    if abs(i - j) > 12:
        return np.zeros((0, 2), int)
    sel = np.random.default_rng(1000 * i + j).choice(len(da), 30, replace=False)
    return np.stack([sel, sel], 1)


KW = dict(tau=0.02, tol=0.006, inlier_deg=3.0, min_votes=8, graph_votes=6, smooth=1, match=_match, profile="off")


def test_roll_recovers_the_spin_the_texture_misses():
    Q, N, X, err, feats = _scene()
    rolling, phi, psi = roll_spin(X, Q, *find_axis(Q, N, 0.02, 0.5, "off")[2:], 0.0)
    assert rolling[ROLL.start + 2:ROLL.stop - 2].all() and not rolling[:ROLL.start - 4].any()
    assert not rolling[ROLL.stop + 4:].any()
    chain = spin_mixed(feats, X, Q, N, **KW)
    assert np.array_equal(chain.theta, spin_closure(feats, X, Q, N, **{k: v for k, v in KW.items() if k != "graph_votes"}).theta)
    assert np.degrees(np.abs(chain.theta - err))[ROLL.stop:].min() > 15.0  # the texture saw 40 % of 30°
    roll = spin_mixed(feats, X, Q, N, table_z=0.0, **KW)
    assert roll.is_revolution and roll.observable and not roll.rejected
    assert np.degrees(np.abs(roll.theta - err)).max() < 1.5
    above = spin_mixed(feats, X, Q, N, table_z=-0.05, **KW)  # lowest point 5 cm above the table: not resting
    assert np.array_equal(above.theta, chain.theta)


def test_texture_close_to_the_roll_is_kept():
    Q, N, X, err, feats = _scene(seen=0.8)  # the texture sees 90 % of the roll: within spin_roll_tol (20 %)
    chain = spin_mixed(feats, X, Q, N, **KW)
    roll = spin_mixed(feats, X, Q, N, table_z=0.0, **KW)
    assert np.array_equal(roll.theta, chain.theta)
    strict = spin_mixed(feats, X, Q, N, table_z=0.0, roll={"tol": 0.05}, **KW)
    assert np.degrees(np.abs(strict.theta - err)).max() < 1.5


def test_sliding_body_is_left_to_the_texture():
    Q, N, X, err, feats = _scene(rolls=False)
    assert np.abs(err).max() == 0.0
    guarded = spin_mixed(feats, X, Q, N, table_z=0.0, **KW)
    assert np.degrees(np.abs(guarded.theta)).max() < 0.5
    unguarded = spin_mixed(feats, X, Q, N, table_z=0.0, roll={"agree": 0.0}, **KW)
    assert np.degrees(np.abs(unguarded.theta)).max() > 50.0  # the roll alone would turn it by 60°


def test_config_refuses_bad_roll_settings():
    assert TrackingConfig().spin_roll is False
    assert TrackingConfig(spin_roll=True).spin_roll
    with pytest.raises(ValueError, match="spin_roll needs"):
        TrackingConfig(spin_roll=True, spin_solver="chain")
    with pytest.raises(ValueError, match="spin_roll_tilt_deg"):
        TrackingConfig(spin_roll_tilt_deg=0.0)
    with pytest.raises(ValueError, match="spin_roll_rate_deg"):
        TrackingConfig(spin_roll_rate_deg=0.0)
    with pytest.raises(ValueError, match="spin_roll_agree"):
        TrackingConfig(spin_roll_agree=1.5)
    with pytest.raises(ValueError, match="spin_roll_tol"):
        TrackingConfig(spin_roll_tol=1.0)
