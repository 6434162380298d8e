"""Tilt closure of egg-like bodies (service/tracking/tilt.py) on constructed matches."""

import numpy as np
import pytest

from service.tracking.tilt import apply_tilt, prolate, tilt_closure
from service.tracking.types import TrackingConfig
from service.transforms import make_X, rotation_angle, so3_exp

A_AX = np.array([1.0, 0.0, 0.0])  # the egg's long axis in O


def _egg_points(rng, n=400, a=0.045, b=0.0325):
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u * np.array([a, b, b])


def _session(rng, n=30, err_deg=8.0, noise=0.001):
    """A textured egg rolling 60° about its long axis and heading 10° about the vertical; the tracked poses carry a
    rotation about a short axis through the centre growing to err_deg from frame 8 on. Features: the points facing
    the camera (+z in W), with ``noise`` m of noise, descriptors = point ids."""
    Q = _egg_points(rng)
    X_true, X_trk = [], []
    for i in range(n):
        s = min(i / (n - 1), 1.0)
        R = so3_exp(np.array([0.0, 0.0, np.radians(10) * s])) @ so3_exp(A_AX * np.radians(60) * s)
        X = make_X(R, np.array([0.5, 0.0, 0.04]))
        X_true.append(X)
        e = np.radians(err_deg) * min(max(i - 8, 0) / 10, 1.0)
        X_trk.append(X @ make_X(so3_exp(np.array([0.0, e, 0.3 * e])), np.zeros(3)))
    feats = []
    for X in X_true:
        P = Q @ X[:3, :3].T + X[:3, 3]
        vis = np.nonzero((Q @ X[:3, :3].T)[:, 2] > 0.005)[0]
        feats.append((P[vis] + rng.normal(scale=noise, size=(len(vis), 3)), vis.astype(np.int64)))
    return Q, np.stack(X_true), np.stack(X_trk), feats


def _match(da, db):
    common, ia, ib = np.intersect1d(da, db, return_indices=True)
    return np.stack([ia, ib], 1) if len(common) else np.zeros((0, 2), int)


def _errs(X, X_true):
    return np.degrees([rotation_angle(a[:3, :3].T @ b[:3, :3]) for a, b in zip(X, X_true)])


def test_tilt_recovered_spin_kept():
    rng = np.random.default_rng(3)
    Q, X_true, X_trk, feats = _session(rng)
    assert _errs(X_trk, X_true).max() > 7.5
    res = tilt_closure(feats, X_trk, Q, A_AX, np.zeros(3), match=_match, tol=0.02)
    assert res.applied and not res.rejected
    X2 = apply_tilt(X_trk, res)
    assert _errs(X2, X_true).max() < 1.5
    assert np.all(np.abs(res.omega @ A_AX) < 1e-9)  # only the short axes move, the spin is left alone
    # the centre of the body stays where the registration put it (rotation about o)
    o = res.centre_O
    assert np.abs((X2[:, :3, :3] @ o + X2[:, :3, 3]) - (X_trk[:, :3, :3] @ o + X_trk[:, :3, 3])).max() < 1e-9


def test_unvoted_frames_untouched_and_cap():
    rng = np.random.default_rng(4)
    Q, X_true, X_trk, feats = _session(rng)
    none = np.zeros(len(X_trk), bool)
    res = tilt_closure(feats, X_trk, Q, A_AX, np.zeros(3), match=_match, voted=none)
    assert res.applied and np.all(res.omega == 0) and np.all(res.votes == 0)
    assert np.array_equal(apply_tilt(X_trk, res), X_trk)
    capped = tilt_closure(feats, X_trk, Q, A_AX, np.zeros(3), match=_match, tol=0.02, max_deg=3.0)
    assert capped.rejected and not capped.applied
    assert np.array_equal(apply_tilt(X_trk, capped), X_trk)


def test_textureless_unchanged():
    rng = np.random.default_rng(5)
    Q, X_true, X_trk, feats = _session(rng)
    empty = [(np.zeros((0, 3)), None)] * len(X_trk)
    res = tilt_closure(empty, X_trk, Q, A_AX, np.zeros(3), match=_match)
    assert np.all(res.omega == 0)


def test_config():
    assert TrackingConfig().spin_tilt  # on by default (docs/tracking-findings.md "Eggs: where the error comes from")
    from service.tracking.tracker import _spin_tilt

    X = np.repeat(np.eye(4)[None], 3, 0)  # no spin closure (spin_closure off): no spin result, nothing done
    assert _spin_tilt([], X, None, None, TrackingConfig(spin_closure=False)) is None
    assert np.array_equal(X, np.repeat(np.eye(4)[None], 3, 0))
    with pytest.raises(ValueError, match="spin_tilt"):
        TrackingConfig(spin_tilt="no")


def test_prolate():
    rng = np.random.default_rng(6)
    Q = _egg_points(rng)
    assert prolate(Q, A_AX, np.zeros(3))
    assert not prolate(Q, np.array([0.0, 1.0, 0.0]), np.zeros(3))  # a short axis
    assert not prolate(Q * np.array([0.6, 1.0, 1.0]), A_AX, np.zeros(3))  # shorter along the axis than across
