"""Anchors from the nearest views (``spin_view_anchors``, service.tracking.spin.spin_closure ``n_view``): on a
constructed set of matches of a cylinder that tilts by 13° and back twice, where the votes between frames of
different tilt in the second tilt are biased by one azimuth step (1.8°) and outnumber those of older anchors, the
chain drifts through the second tilt and keeps the drift at rest; with the older anchors of the nearest view (the
same tilt in the first cycle, the frames at rest before it), whose votes are unbiased, the spin stays within a few
degrees and returns to the truth at rest. Off (0) leaves the chain as it was. Only upright frames take view anchors,
and only upright anchors (``view_upright_deg``): the scene as built has the cylinder's axis 77–90° from the vertical of W
(lying, tilted up and back), where the chain takes none; turned upright (axis vertical, tilted by 13° and back as in a
pivot), every frame is upright and takes them."""

from __future__ import annotations

import numpy as np
import pytest

from service.tracking import spin as spin_mod
from service.tracking.spin import _nearest_views, _upright, find_axis, spin_closure, spin_matrix
from service.tracking.types import TrackingConfig
from service.transforms import make_X, so3_exp
from tests.tracking.cylinder_feats import N_AZ, cylinder_features
from tests.tracking.test_spin import _cylinder_model

CYCLE = np.concatenate([np.linspace(1.3, 13.0, 10), np.full(5, 13.0), np.linspace(11.7, 0.0, 10)])  # tilt (°)
PROFILE = np.concatenate([np.zeros(10), CYCLE, np.zeros(15), CYCLE, np.zeros(15)])
SECOND = 50  # first frame of the second tilt
TWIST_ERR = 3.0  # the tracker's constant spin error (°) after frame 0: the correction to find


def _scene(upright: bool = False):
    """Model, tracked poses, true spin error and features. The cylinder's axis (x of O) lies along x of W at frame 0
    and tilts up from the table by 13° and back; ``upright``: the whole scene turned by −90° about y of W (the axis
    vertical at frame 0, tilted by 13° about a horizontal line; the same matches)."""
    Q, N = _cylinder_model()
    ok, _, a, c = find_axis(Q, N, 0.02, 0.5, "off")
    assert ok
    e1 = np.cross(a, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    X_trk = np.stack([make_X(so3_exp(e1 * np.radians(t)), np.array([0.5, 0.0, 0.1])) for t in PROFILE])
    if upright:
        X_trk = make_X(so3_exp(np.array([0.0, -np.pi / 2, 0.0])), np.zeros(3)) @ X_trk
    err = np.radians(np.full(len(PROFILE), TWIST_ERR))
    err[0] = 0.0
    X_true = np.stack([X @ spin_matrix(a, c, e) for X, e in zip(X_trk, err)])
    return Q, N, X_trk, err, cylinder_features(a, c, e1, X_true)


def _match(da: np.ndarray, db: np.ndarray) -> np.ndarray:
    """Matches by point id (bytes 0-1), the frames (byte 2) deciding how many and whether they are biased: the same
    view (tilt within 0.5°) 16 unbiased (10 across the two cycles); views up to 3° apart 16, biased by one azimuth
    step in the second tilt, unbiased elsewhere (4 when more than 3 frames apart); farther views none."""
    i, j = int(da[0, 2]), int(db[0, 2])
    ids = da[:, 0].astype(int) + 256 * da[:, 1].astype(int)
    rng = np.random.default_rng(1000 * i + j)
    dt = abs(PROFILE[i] - PROFILE[j])
    if dt < 0.5:
        m, shift = (10 if max(i, j) >= SECOND > min(i, j) else 16), 0
    elif dt > 3.0:
        return np.zeros((0, 2), int)
    elif min(i, j) >= SECOND - 1:
        m, shift = 16, -1
    else:
        m, shift = (16 if abs(i - j) <= 3 else 4), 0
    sel = rng.choice(len(ids), m, replace=False)
    ring, az = ids[sel] // N_AZ, ids[sel] % N_AZ
    return np.stack([sel, ring * N_AZ + (az + shift) % N_AZ], 1)


KW = dict(tau=0.02, tol=0.006, inlier_deg=3.0, min_votes=8, smooth=1, match=_match, profile="off")


def _err_deg(r, err):
    return np.degrees(np.abs(r.theta - err))


def test_view_anchors_hold_the_spin_through_a_biased_tilt():
    Q, N, X, err, feats = _scene()
    chain = spin_closure(feats, X, Q, N, **KW)
    view = spin_closure(feats, X, Q, N, n_view=4, **KW)
    for r in (chain, view):
        assert r.is_revolution and r.observable and not r.rejected
    e0, e4 = _err_deg(chain, err), _err_deg(view, err)
    assert e0[:SECOND].max() < 0.5 and e4[:SECOND].max() < 0.5  # the first tilt: unbiased votes
    assert e0[SECOND + len(CYCLE):].min() > 10.0  # the chain keeps its drift at rest after the second tilt
    assert e4.max() < 4.0
    assert e4[SECOND + len(CYCLE):].max() < 0.5  # back at rest: the view of the frames before the tilt


def test_off_is_the_chain():
    Q, N, X, err, feats = _scene()
    a = spin_closure(feats, X, Q, N, **KW)
    b = spin_closure(feats, X, Q, N, n_view=0, **KW)
    assert np.array_equal(a.theta, b.theta) and np.array_equal(a.votes, b.votes)
    on = spin_closure(feats, X, Q, N, n_view=4, **KW)  # the switch is what changes the chain on this scene
    assert not np.array_equal(a.theta, on.theta)


def test_nearest_views_order_and_ties():
    R = [so3_exp(np.array([0.0, 0.0, np.radians(d)])) for d in (0.0, 5.0, 1.0, 1.0, 9.0)]
    Xc = np.stack([make_X(r, np.zeros(3)) for r in R])
    got = _nearest_views(Xc, [0, 1, 2, 3, 4], Xc[2], 3)
    assert got[:2] == [3, 2]  # equal angles: the latest first
    assert got[2] == 0


def test_config_refuses_negative_view_anchors():
    assert TrackingConfig(spin_view_anchors=4).spin_view_anchors == 4
    with pytest.raises(ValueError, match="spin_view_anchors"):
        TrackingConfig(spin_view_anchors=-1)
    for bad in (0.0, -5.0, 91.0, float("nan"), True, "45"):
        with pytest.raises(ValueError, match="spin_view_upright_deg"):
            TrackingConfig(spin_view_upright_deg=bad)


def test_upright_frames():
    a = np.array([0.0, 0.0, 1.0])
    X = np.stack([make_X(so3_exp(np.array([np.radians(d), 0.0, 0.0])), np.zeros(3)) for d in (0.0, 13.0, 44.0, 46.0,
                                                                                              88.0, 180.0)])
    assert _upright(X, a, 45.0).tolist() == [True, True, True, False, False, True]  # either way up
    assert _upright(X, a, 90.0).all()
    assert _upright(X, a, 10.0).tolist() == [True, False, False, False, False, True]


def test_view_anchors_only_while_upright(monkeypatch):
    Q, N, X, err, feats = _scene(upright=True)
    on = spin_closure(feats, X, Q, N, n_view=4, **KW)
    same = spin_closure(feats, X, Q, N, n_view=4, view_upright_deg=45.0, **KW)  # tilts of 13°: every frame upright
    assert np.array_equal(on.theta, same.theta) and np.array_equal(on.votes, same.votes)
    e = _err_deg(same, err)  # the pivot's gain is kept
    assert e.max() < 4.0 and e[SECOND + len(CYCLE):].max() < 0.5
    assert _err_deg(spin_closure(feats, X, Q, N, **KW), err)[SECOND + len(CYCLE):].min() > 10.0
    seen = []
    orig = spin_mod._nearest_views

    def spy(Xc, frames, Xp, k):
        seen.append((Xp.copy(), [Xc[j].copy() for j in frames]))
        return orig(Xc, frames, Xp, k)

    monkeypatch.setattr(spin_mod, "_nearest_views", spy)
    low = spin_closure(feats, X, Q, N, n_view=4, view_upright_deg=5.0, **KW)  # the tilted frames are not upright
    a = on.axis_O
    tilt = lambda Xk: np.degrees(np.arccos(min(1.0, abs((Xk[:3, :3] @ a)[2]))))
    assert seen and all(tilt(Xp) <= 5.0 and all(tilt(Xj) <= 5.0 for Xj in cand) for Xp, cand in seen)
    assert len(seen) < sum(tilt(Xk) <= 5.0 for Xk in X)  # fewer calls than frames: the tilts took none
    assert not np.array_equal(low.theta, on.theta)


def test_lying_body_takes_no_view_anchors():
    Q, N, X, err, feats = _scene()
    chain = spin_closure(feats, X, Q, N, **KW)
    view = spin_closure(feats, X, Q, N, n_view=4, view_upright_deg=45.0, **KW)
    assert chain.is_revolution and chain.observable
    assert np.array_equal(chain.theta, view.theta) and np.array_equal(chain.votes, view.votes)
    every = spin_closure(feats, X, Q, N, n_view=4, view_upright_deg=90.0, **KW)  # unrestricted: it changes the chain
    assert not np.array_equal(chain.theta, every.theta)
