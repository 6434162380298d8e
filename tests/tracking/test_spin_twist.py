"""The body's twist smoothed instead of the spin correction (service.tracking.spin.smooth_twist,
``spin_twist_smooth``): a cylinder pivoted by 13° and back whose tracked rotation about its axis jitters by about 1.5°
per frame, and whose texture votes are biased by 7.2° for six consecutive frames. The correction must carry the jitter:
the chain with its median over the correction leaves errors of several degrees, the median over the corrected twist
removes both; a twist that really turns (a 60° roll) is kept."""

from __future__ import annotations

import numpy as np
import pytest

from service.tracking.spin import find_axis, smooth_twist, spin_closure, spin_matrix, twist_angles
from service.tracking.types import TrackingConfig
from service.transforms import make_X, so3_exp
from tests.tracking.cylinder_feats import N_AZ, cylinder_features
from tests.tracking.test_spin import _cylinder_model

N = 80
BURST = range(50, 56)  # the votes of these frames against any other frame are shifted by 4 azimuth steps (7.2°)


def _scene(twist_deg: np.ndarray):
    Q, Nq = _cylinder_model()
    ok, _, a, c = find_axis(Q, Nq, 0.02, 0.5, "off")
    assert ok
    e1 = np.cross(a, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    k = np.arange(N)
    tilt = np.radians(13.0) * np.clip(np.minimum(k - 20, 60 - k) / 20.0, 0.0, 1.0)  # pivot 20-60, up and back
    X_tilt = np.stack([make_X(so3_exp(e1 * t), np.array([0.5, 0.0, 0.1])) for t in tilt])
    jitter = np.radians(np.random.default_rng(4).normal(0.0, 1.5, N))
    jitter[0] = 0.0
    X_trk = np.stack([X @ spin_matrix(a, c, j) for X, j in zip(X_tilt, jitter)])  # the tracker's twist jitters
    X_true = np.stack([X @ spin_matrix(a, c, t) for X, t in zip(X_tilt, np.radians(twist_deg))])
    feats = cylinder_features(a, c, e1, X_true)
    need = np.radians(twist_deg) - jitter  # X_true = X_trk S(need)
    return Q, Nq, X_trk, need, feats


def _match(da: np.ndarray, db: np.ndarray) -> np.ndarray:
    """30 matches per pair by point id; a pair with exactly one frame of BURST is shifted by 4 azimuth steps."""
    i, j = int(da[0, 2]), int(db[0, 2])
    ids = da[:, 0].astype(int) + 256 * da[:, 1].astype(int)
    sel = np.random.default_rng(1000 * i + j).choice(len(ids), 30, replace=False)
    shift = 4 * ((i in BURST) - (j in BURST))
    ring, az = ids[sel] // N_AZ, ids[sel] % N_AZ
    return np.stack([sel, ring * N_AZ + (az + shift) % N_AZ], 1)


KW = dict(tau=0.02, tol=0.006, inlier_deg=3.0, min_votes=8, match=_match, profile="off")


def _err(r, need):
    return np.degrees(np.abs(r.theta - need))


def test_twist_smoothing_removes_jitter_and_vote_burst():
    twist = np.concatenate([np.zeros(20), np.linspace(0.0, 3.0, 40), np.full(20, 3.0)])  # the pivot twists by 3°
    Q, Nq, X, need, feats = _scene(twist)
    chain = spin_closure(feats, X, Q, Nq, smooth=5, **KW)  # the median over the correction
    raw = spin_closure(feats, X, Q, Nq, smooth=1, **KW)
    assert chain.is_revolution and chain.observable and not chain.rejected
    assert _err(chain, need)[BURST].max() > 5.0  # six biased frames outlast a 5-frame median
    assert _err(chain, need).max() > 3.0
    assert _err(raw, need)[BURST].min() > 6.0
    out = smooth_twist(raw, X, 15, 120.0)
    assert out.theta[0] == 0.0 and not out.rejected
    assert _err(out, need).max() < 1.0


def test_a_real_twist_is_kept_and_settings():
    twist = np.concatenate([np.zeros(30), np.linspace(0.0, 60.0, 30), np.full(20, 60.0)])  # a 60° roll
    Q, Nq, X, need, feats = _scene(twist)
    global BURST
    BURST, saved = range(0), BURST  # exact votes
    try:
        raw = spin_closure(feats, X, Q, Nq, smooth=1, **KW)
    finally:
        BURST = saved
    out = smooth_twist(raw, X, 15, 120.0)
    assert _err(out, need).max() < 1.0
    tau = twist_angles(X, raw.axis_O)  # the twist of the tracked poses (tilt about e1 ⟂ a, then jitter) is the jitter
    assert np.degrees(np.abs(tau - (np.radians(twist) - need))).max() < 1e-6
    assert smooth_twist(raw, X, 1) is raw  # size 1: unchanged
    assert smooth_twist(raw, X, 15, 30.0).rejected  # above the cap: not applied
    assert TrackingConfig().spin_twist_smooth >= 0
    with pytest.raises(ValueError, match="spin_twist_smooth"):
        TrackingConfig(spin_twist_smooth=-1)
    with pytest.raises(ValueError, match="spin_twist_smooth"):
        TrackingConfig(spin_twist_smooth=2.5)
