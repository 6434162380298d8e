"""No spin during a topple (service.tracking.fall, ``spin_fall``): a cylinder standing on its base tips over (20
frames at 1°/frame, then 10 frames at 7°/frame onto its side) without turning about its axis, while the tracked
poses add a false spin of 1°/frame and then 2°/frame (40° by the landing) and the texture has no match during the
fall nor across it: the mixed estimate keeps the 40°, the no-twist increments remove it (< 0.5° in every frame). A
texture that follows the fall is kept (the guard), and a pivot (15° of tilt and back, with a real spin) is not a
topple: both give the mixed estimate itself."""

from __future__ import annotations

import numpy as np
import pytest

from service.tracking.fall import spin_fall, topple_frames, twist_steps
from service.tracking.spin import find_axis, spin_matrix, spin_mixed
from service.tracking.types import TrackingConfig
from service.transforms import make_X, so3_exp
from tests.tracking.cylinder_feats import cylinder_features
from tests.tracking.test_spin import _cylinder_model

N_FR, SLOW, FAST, LAND = 70, 20, 40, 50  # tilt 1°/frame from SLOW, 7°/frame from FAST, lying from LAND (90°)


def _scene(pivot: bool = False):
    """Model (Q, N) in O (axis along x_O), tracked poses, the spin correction they need, and features of the true
    surface. ``pivot``: the body tilts 15° and back over frames 20-49 and turns 10° about its axis meanwhile."""
    Q, N = _cylinder_model()
    ok, _, a, c = find_axis(Q, N, 0.02, 0.5, "off")
    assert ok
    i = np.arange(N_FR)
    if pivot:
        tilt = np.radians(15.0) * np.sin(np.pi * np.clip((i - SLOW) / 30.0, 0, 1))
        spin = np.radians(10.0) * np.clip((i - SLOW) / 30.0, 0, 1)  # a real turn about the axis
        false = np.zeros(N_FR)
    else:
        tilt = np.radians(np.clip(i - SLOW, 0, FAST - SLOW) + 7.0 * np.clip(i - FAST, 0, LAND - FAST))
        spin = np.zeros(N_FR)  # no turn about the axis while it falls
        false = np.radians(np.clip(i - SLOW, 0, FAST - SLOW) + 2.0 * np.clip(i - FAST, 0, LAND - FAST))
    R0 = so3_exp(np.array([0.0, -np.pi / 2, 0.0]))  # x_O (the axis) vertical: standing at frame 0
    X_true = np.stack([make_X(so3_exp(np.array([0.0, t, 0.0])) @ R0, np.array([0.5, 0.0, 0.1])) @
                       spin_matrix(a, c, s) for t, s in zip(tilt, spin)])
    err = spin - false if not pivot else spin  # X_trk S(err) = X_true
    X_trk = np.stack([X @ spin_matrix(a, c, -e) for X, e in zip(X_true, err)])
    feats = cylinder_features(a, c, np.array([0.0, 1.0, 0.0]) - a[1] * a, X_true)
    return Q, N, X_trk, err, feats


def _phase(i: int) -> int:
    return 0 if i < SLOW else (1 if i < LAND else 2)


def _match_still(da: np.ndarray, db: np.ndarray) -> np.ndarray:
    """30 matches by point id between frames of the same still stretch (before the fall, after it); none else."""
    i, j = int(da[0, 2]), int(db[0, 2])
    if _phase(i) != _phase(j) or _phase(i) == 1:
        return np.zeros((0, 2), int)
    sel = np.random.default_rng(1000 * i + j).choice(len(da), 30, replace=False)
    return np.stack([sel, sel], 1)


def _match_near(da: np.ndarray, db: np.ndarray) -> np.ndarray:
    """30 matches by point id between frames at most 2 apart (the texture follows the motion)."""
    i, j = int(da[0, 2]), int(db[0, 2])
    if abs(i - j) > 2:
        return np.zeros((0, 2), int)
    sel = np.random.default_rng(1000 * i + j).choice(len(da), 30, replace=False)
    return np.stack([sel, sel], 1)


KW = dict(tau=0.02, tol=0.006, inlier_deg=3.0, min_votes=8, graph_votes=6, smooth=1, profile="off")


def test_topple_frames_and_twist_steps():
    Q, N, X, err, _ = _scene()
    a = find_axis(Q, N, 0.02, 0.5, "off")[2]
    f = topple_frames(X, a)
    idx = np.nonzero(f)[0]
    assert abs(idx[0] - SLOW) <= 2 and abs(idx[-1] - LAND) <= 2 and f[SLOW + 2:LAND - 1].all()
    assert np.allclose(np.cumsum(twist_steps(X, a)), -err, atol=1e-7)  # the twist the tracked poses add: −err
    Qp, Np, Xp, _, _ = _scene(pivot=True)
    assert not topple_frames(Xp, a).any()


def test_no_twist_removes_the_false_spin_the_texture_cannot_see():
    Q, N, X, err, feats = _scene()
    mixed = spin_mixed(feats, X, Q, N, match=_match_still, **KW)
    res, used = spin_fall(feats, X, Q, N, match=_match_still, **KW)
    assert np.degrees(np.abs(mixed.theta - err)).max() > 30.0  # the 40° false spin stays
    assert used[SLOW + 2:LAND - 1].all() and not used[:SLOW - 2].any()
    assert np.degrees(np.abs(res.theta - err)).max() < 0.5


def test_texture_that_follows_the_fall_is_kept_and_a_pivot_is_not_a_topple():
    Q, N, X, err, feats = _scene()
    mixed = spin_mixed(feats, X, Q, N, match=_match_near, **KW)
    assert np.degrees(np.abs(mixed.theta - err)).max() < 2.0  # the texture sees the fall here
    res, used = spin_fall(feats, X, Q, N, match=_match_near, **KW)
    assert not used.any() and np.array_equal(res.theta, mixed.theta)
    Q, N, X, err, feats = _scene(pivot=True)
    mixed = spin_mixed(feats, X, Q, N, match=_match_still, **KW)
    res, used = spin_fall(feats, X, Q, N, match=_match_still, **KW)
    assert not used.any() and np.array_equal(res.theta, mixed.theta)


def test_config_refuses_bad_fall_settings():
    assert TrackingConfig().spin_fall
    with pytest.raises(ValueError, match="spin_fall_min_deg"):
        TrackingConfig(spin_fall_min_deg=0.0)
    with pytest.raises(ValueError, match="spin_fall_tol_deg"):
        TrackingConfig(spin_fall_tol_deg=-1.0)
    with pytest.raises(ValueError, match="spin_fall_rate_deg"):
        TrackingConfig(spin_fall_rate_deg=-0.1)
