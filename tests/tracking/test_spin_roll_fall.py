"""The rolling constraint with the fall without spin (``fall.with_roll``; ``spin_roll`` with ``spin_fall``): on the
rolling cylinder of test_spin_roll (60° of roll, the tracked poses keep half of it), the roll's increments replace the
texture only where the texture is weak (mean votes per frame of the stretch below ``strong``): a texture without
matches in the roll is replaced (within 1.5° of the true spin in every frame), a strongly voted texture that lags is
kept unless the vote rule is off; topple frames never take the roll; the surface-of-revolution candidates
(``radius`` "widest") find the roll of a model seen only from above, where the model's own lowest point never
reaches the table."""

from __future__ import annotations

import numpy as np
import pytest

from service.tracking.fall import with_roll
from service.tracking.spin import find_axis, roll_spin, spin_closure
from service.tracking.types import TrackingConfig
from tests.tracking.test_spin import R_CYL
from tests.tracking.test_spin_roll import ROLL, _match, _scene

KW = dict(tau=0.02, tol=0.006, inlier_deg=3.0, min_votes=8, smooth=1, profile="off", sep=0.5, max_deg=0.0)


def _blind(da: np.ndarray, db: np.ndarray) -> np.ndarray:
    """The matches of ``_match``, none where either frame is in the roll (a texture without votes there)."""
    i, j = int(da[0, 2]), int(db[0, 2])
    if ROLL.start <= i < ROLL.stop + 2 or ROLL.start <= j < ROLL.stop + 2:
        return np.zeros((0, 2), int)
    return _match(da, db)


def _run(feats, X, Q, N, match, roll: dict, topple=None):
    axis = find_axis(Q, N, 0.02, 0.5, "off")
    kw = dict(KW, match=match, axis=axis)
    res = spin_closure(feats, X, Q, N, **kw)
    n = len(X)
    none = np.zeros(n, bool)
    out = with_roll(res, feats, X, Q, N, none, np.zeros(n), none if topple is None else topple, 0.0, roll, **kw)
    return res, out


def test_weak_texture_takes_the_roll():
    Q, N, X, err, feats = _scene()
    res, out = _run(feats, X, Q, N, _blind, {"strong": 60.0})
    assert np.degrees(np.abs(res.theta - err))[ROLL.stop:].min() > 15.0  # interpolated over the roll: lags
    assert np.degrees(np.abs(out.theta - err)).max() < 1.5


def test_strong_texture_is_kept():
    Q, N, X, err, feats = _scene()  # the texture sees 40 % of what the tracker misses, with many votes
    res, out = _run(feats, X, Q, N, _match, {"strong": 60.0})
    assert res.votes[ROLL.start:ROLL.stop].mean() >= 60
    assert out is res
    res, free = _run(feats, X, Q, N, _match, {"strong": None})  # the guard of spin_mixed alone: the roll is used
    assert np.degrees(np.abs(free.theta - err)).max() < 1.5


def test_topple_frames_never_take_the_roll():
    Q, N, X, err, feats = _scene()
    topple = np.zeros(len(X), bool)
    topple[ROLL.start - 2:ROLL.stop + 2] = True
    res, out = _run(feats, X, Q, N, _blind, {"strong": 60.0}, topple=topple)
    assert out is res


def test_widest_candidates_on_a_model_seen_from_above():
    Q, N, X, err, feats = _scene()
    up = Q[:, 2] > R_CYL  # the upper half only: its lowest point stays >= R/2 above the table (tracked turn <= 30°)
    a, c = find_axis(Q, N, 0.02, 0.5, "off")[2:]
    rolling, _, _ = roll_spin(X, Q[up], a, c, 0.0, margin=0.3 * R_CYL)
    assert not rolling.any()
    rolling, phi, _ = roll_spin(X, Q[up], a, c, 0.0, margin=0.3 * R_CYL, radius="widest")
    assert rolling[ROLL.start + 2:ROLL.stop - 2].all() and not rolling[:ROLL.start - 4].any()
    assert abs(abs(np.degrees(phi[-1] - phi[0])) - 60.0) < 3.0


def test_config_refuses_bad_settings():
    cfg = TrackingConfig()
    assert cfg.spin_roll is False and cfg.spin_roll_radius == "contact" and cfg.spin_roll_votes == 60.0
    with pytest.raises(ValueError, match="spin_roll_radius"):
        TrackingConfig(spin_roll_radius="max")
    with pytest.raises(ValueError, match="spin_roll_votes"):
        TrackingConfig(spin_roll_votes=0.0)
    assert TrackingConfig(spin_roll_votes=None).spin_roll_votes is None
