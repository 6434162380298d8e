"""The entry of a topple's stretch (service.tracking.spin, ``spin_fall_entry``): a stretch of no-twist increments starts
from the median corrected twist of the chain's last voted frames (``entry_spin``), not from the raw value of its entry
frame alone, whose error the increments would carry to the stretch's end; other stretches keep the raw value."""

from __future__ import annotations

import numpy as np
import pytest

from service.tracking.spin import entry_spin, find_axis, spin_closure, spin_matrix, twist_angles
from service.tracking.types import TrackingConfig
from service.transforms import make_X, so3_exp
from tests.tracking.cylinder_feats import N_AZ, cylinder_features
from tests.tracking.test_spin import _cylinder_model

ENTRY, STRETCH = 19, range(20, 30)  # the last chain-voted frame, then the frames of increments
SHIFT = 2  # the entry frame's matches are off by 2 azimuth steps (3.6°): its raw chain value jitters so
WOBBLE = np.radians(1.0)  # the tracker's twist jitters by ±1° per frame while the body stands still


def _scene():
    Q, N = _cylinder_model()
    ok, _, a, c = find_axis(Q, N, 0.02, 0.5, "off")
    assert ok
    n = 30
    err = WOBBLE * np.where(np.arange(n) % 2, 1.0, -1.0)  # the correction to find: X_true = X_trk S(err)
    err[0] = 0.0
    e1 = np.cross(a, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    # the body tips slowly (0.2°/frame) without turning about its axis; the tracked poses add the twist jitter −err
    X_true = np.stack([make_X(so3_exp(e1 * np.radians(0.2) * i), np.array([0.5, 0.0, 0.1])) for i in range(n)])
    X_trk = np.stack([X @ spin_matrix(a, c, -e) for X, e in zip(X_true, err)])
    return Q, N, X_trk, err, cylinder_features(a, c, e1, X_true)


def _match(da: np.ndarray, db: np.ndarray) -> np.ndarray:
    """20 matches by point id (bytes 0-1) per pair; those of the entry frame shifted by SHIFT azimuth steps."""
    i, j = int(da[0, 2]), int(db[0, 2])
    ids = da[:, 0].astype(int) + 256 * da[:, 1].astype(int)
    sel = np.random.default_rng(1000 * i + j).choice(len(ids), 20, replace=False)
    ring, az = ids[sel] // N_AZ, ids[sel] % N_AZ
    shift = SHIFT if i == ENTRY else 0
    return np.stack([sel, ring * N_AZ + (az + shift) % N_AZ], 1)


KW = dict(tau=0.02, tol=0.006, inlier_deg=3.0, min_votes=8, smooth=1, match=_match, profile="off")


def _stretch(err):
    """Fast frames (the stretch) and their increments: here the true ones, so only the entry value can be off."""
    fast = np.zeros(len(err), bool)
    fast[STRETCH.start:STRETCH.stop] = True
    return fast, err.copy()


def test_topple_entry_from_the_median_of_the_voted_frames():
    Q, N, X, err, feats = _scene()
    fast, theta_fast = _stretch(err)
    old = spin_closure(feats, X, Q, N, fast=fast, theta_fast=theta_fast, **KW)
    new = spin_closure(feats, X, Q, N, fast=fast, theta_fast=theta_fast, entry_fit=15, entry_level=fast, **KW)
    e_old = np.degrees(np.abs(old.theta - err))
    e_new = np.degrees(np.abs(new.theta - err))
    assert e_old[:ENTRY].max() < 0.5 and e_new[:ENTRY].max() < 0.5  # the chain follows the tracker's jitter
    assert e_old[ENTRY] > 2.5  # the entry frame's raw value is off by its own error ...
    assert e_old[STRETCH.start:STRETCH.stop].min() > 2.5  # ... and the old entry carries it through the stretch
    assert e_new[STRETCH.start:STRETCH.stop].max() < 0.5  # the median of the voted frames' corrected twist
    assert np.array_equal(new.theta[:STRETCH.start], old.theta[:STRETCH.start])  # the voted frames are unchanged
    for kw in (dict(entry_fit=0, entry_level=fast), dict(entry_fit=15, entry_level=np.zeros(len(X), bool)),
               dict(entry_fit=15)):  # off, a stretch that is not a topple's, no topple given: the raw entry
        r = spin_closure(feats, X, Q, N, fast=fast, theta_fast=theta_fast, **kw, **KW)
        assert np.array_equal(r.theta, old.theta)


def test_entry_spin_median_and_fallbacks():
    n = 12
    votes = np.full(n, 30)
    fixed = np.zeros(n, bool)
    twist = np.radians(np.linspace(0.0, 5.0, n))  # the tracked twist: any, it cancels
    level = np.radians(2.0)  # the body's corrected twist: constant
    theta = level - twist
    theta[-1] += np.radians(4.0)  # the entry frame is off by +4°
    theta[-3] -= np.radians(6.0)  # and one earlier frame by −6°
    got = entry_spin(theta, votes, fixed, twist, n - 1, 7)
    assert abs(np.degrees(got - (level - twist[-1]))) < 1e-9
    assert entry_spin(theta, votes, fixed, twist, n - 1, 2) == theta[-1]  # fewer than 3 frames: the raw value
    fixed[:9] = True  # an earlier stretch up to frame 8: only frames 9-11 are of the current chain run (the median
    got3 = entry_spin(theta, votes, fixed, twist, n - 1, 7)  # of +0°, −6°, +4°: 0° off)
    assert abs(np.degrees(got3 - (level - twist[-1]))) < 1e-9
    theta[-2] += np.radians(3.0)
    assert abs(np.degrees(entry_spin(theta, votes, fixed, twist, n - 1, 7) - (level - twist[-1])) - 3.0) < 1e-9
    fixed[:10] = True  # two voted frames left: the raw value
    assert entry_spin(theta, votes, fixed, twist, n - 1, 7) == theta[-1]
    votes[-1] = 0  # an entry frame that was not voted (frame 0, or interpolated): its own value
    assert entry_spin(theta, votes, np.zeros(n, bool), twist, n - 1, 7) == theta[-1]
    assert np.allclose(twist_angles(np.stack([np.eye(4)] * 3), np.array([0.0, 0.0, 1.0])), 0.0)


def test_config_fall_entry():
    assert TrackingConfig(spin_fall_entry=0).spin_fall_entry == 0
    assert TrackingConfig(spin_fall_entry=7).spin_fall_entry == 7
    for bad in (1, 2, -1, 7.0, True, "7"):
        with pytest.raises(ValueError, match="spin_fall_entry"):
            TrackingConfig(spin_fall_entry=bad)
