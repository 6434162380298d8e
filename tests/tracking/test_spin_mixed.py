"""Mixed spin estimate (service.tracking.spin, ``spin_solver`` "mixed"): on a constructed set of matches where the
per-frame chain fails during a fast fall (few matches; pairs 3-8 frames apart across the fall are biased and outvote
the nearest two) and a pose graph alone would fail in a still stretch (every pair has only 4 matches, below a
link's minimum, while the pooled anchors of the chain have enough), the mixed estimate recovers the spins in both;
without a fast stretch, or when the chain pooled enough votes in it, it is the chain."""

from __future__ import annotations

import numpy as np
import pytest

from service.tracking.spin import fast_frames, find_axis, spin_closure, spin_matrix, spin_mixed
from service.tracking.types import TrackingConfig
from service.transforms import make_X, so3_exp
from tests.tracking.cylinder_feats import N_AZ, cylinder_features
from tests.tracking.test_spin import _cylinder_model

FALL = range(20, 30)  # tracked rotation 9°/frame about an axis across the body (frame 29 at 90°)
SLOW = 40  # from here on each pair of frames has 4 matches


def _scene():
    Q, N = _cylinder_model()
    ok, _, a, c = find_axis(Q, N, 0.02, 0.5, "off")
    assert ok
    n = 60
    tilt = np.clip(np.arange(n) - 19, 0, 10) * np.radians(9.0)  # 0 before the fall, 90° after
    err = np.radians(np.concatenate([np.zeros(20), np.linspace(3, 30, 10), np.full(10, 30.0), np.full(20, 40.0)]))
    e1 = np.cross(a, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    # tracked poses: the tilt alone; the body also turns about its axis by err (missed by the tracker; at frame 40
    # by 10° at once while still), so X_true = X_trk S(err) and err is the correction to find
    X_trk = np.stack([make_X(so3_exp(e1 * t), np.array([0.5, 0.0, 0.1])) for t in tilt])
    X_true = np.stack([X @ spin_matrix(a, c, e) for X, e in zip(X_trk, err)])
    # surface points in O: azimuth k (1.8° steps) about the axis in rings along it; in W with the true poses
    feats = cylinder_features(a, c, e1, X_true)
    return Q, N, X_trk, err, feats


def _match(da: np.ndarray, db: np.ndarray) -> np.ndarray:
    """Matches by point id (bytes 0-1) with the frames (byte 2) deciding how many and whether they are biased."""
    i, j = int(da[0, 2]), int(db[0, 2])
    k = abs(i - j)
    ids = da[:, 0].astype(int) + 256 * da[:, 1].astype(int)
    rng = np.random.default_rng(1000 * i + j)
    tilt = np.clip(np.array([i, j]) - 19, 0, 10)  # the fall's steps of 9° (as in _scene)
    if tilt[0] == tilt[1]:  # the same view
        m, shift = (4 if max(i, j) >= SLOW else 40), 0
    elif k <= 2:
        m, shift = 8, 0
    elif k <= 8:
        m, shift = 12, 4  # 27-72° of view apart across the fall: biased by 4 azimuth steps (7.2°)
    else:
        return np.zeros((0, 2), int)  # no common view
    sel = rng.choice(len(ids), m, replace=False)
    ring, az = ids[sel] // N_AZ, ids[sel] % N_AZ
    return np.stack([sel, ring * N_AZ + (az + shift) % N_AZ], 1)


KW = dict(tau=0.02, tol=0.006, inlier_deg=3.0, smooth=1, match=_match, profile="off")


def _err_deg(r, err):
    return np.degrees(np.abs(r.theta - err))


def test_mixed_recovers_fall_and_slow_stretch_where_the_chain_fails():
    Q, N, X, err, feats = _scene()
    fast = fast_frames(X)
    assert fast[FALL.start] and fast[FALL.stop - 1] and not fast[:12].any() and not fast[38:].any()
    chain = spin_closure(feats, X, Q, N, min_votes=8, **KW)
    mixed = spin_mixed(feats, X, Q, N, min_votes=8, graph_votes=6, **KW)
    for r in (chain, mixed):
        assert r.is_revolution and r.observable and not r.rejected
    assert _err_deg(chain, err)[FALL.stop:].max() > 5.0  # the chain follows the biased fall links
    assert _err_deg(mixed, err).max() < 1.5


def test_no_fast_stretch_is_the_chain():
    Q, N, X, err, feats = _scene()
    X_still = X.copy()
    X_still[:, :3, :3] = X[0, :3, :3]  # no tracked rotation at all: no fast stretch
    assert not fast_frames(X_still).any()
    a = spin_closure(feats, X_still, Q, N, min_votes=8, **KW)
    b = spin_mixed(feats, X_still, Q, N, min_votes=8, graph_votes=6, **KW)
    assert np.array_equal(a.theta, b.theta)
    X2 = _scene()[2]
    c = spin_closure(feats, X2, Q, N, min_votes=8, **KW)
    d = spin_mixed(feats, X2, Q, N, min_votes=8, graph_votes=6, fast_votes=10, **KW)  # the fall has 20-48 votes
    assert np.array_equal(c.theta, d.theta)


def test_config_refuses_bad_mixed_settings():
    assert TrackingConfig(spin_solver="mixed").spin_solver == "mixed"
    with pytest.raises(ValueError, match="spin_mixed_span"):
        TrackingConfig(spin_mixed_span=0)
    with pytest.raises(ValueError, match="spin_mixed_rate_deg"):
        TrackingConfig(spin_mixed_rate_deg=-1.0)
    with pytest.raises(ValueError, match="spin_mixed_dilate"):
        TrackingConfig(spin_mixed_dilate=-1)
