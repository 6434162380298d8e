"""The tilt closure kept near the frames it measured (``spin_tilt_reach``, ``tilt.reach_weights``)."""

import numpy as np
import pytest

from service.tracking.tilt import apply_tilt, reach_weights, tilt_closure
from service.tracking.types import TrackingConfig
from tests.tracking.test_tilt import A_AX, _errs, _match, _session


def test_reach_weights():
    v = np.zeros(20, bool)
    v[[0, 5, 6, 15]] = True  # frame 0 is the gauge, not a measured frame
    w = reach_weights(v, 4)
    assert np.allclose(w, [0, 0, 0.25, 0.5, 0.75, 1, 1, 0.75, 0.5, 0.25, 0, 0, 0.25, 0.5, 0.75, 1, 0.75, 0.5, 0.25, 0])
    one = np.zeros(10, bool)
    one[3] = True
    assert np.allclose(reach_weights(one, 2), [0, 0, 0.5, 1, 0.5, 0, 0, 0, 0, 0])
    assert np.all(reach_weights(np.zeros(5, bool), 3) == 0)


def test_correction_not_held_beyond_reach():
    rng = np.random.default_rng(3)
    Q, X_true, X_trk, feats = _session(rng)
    n = len(X_trk)
    voted = np.zeros(n, bool)
    voted[:20] = True  # measured up to frame 19, then nothing: the closure holds frame 19's correction to the end
    held = tilt_closure(feats, X_trk, Q, A_AX, np.zeros(3), match=_match, tol=0.02, voted=voted, smooth=1)
    assert held.applied and np.degrees(np.linalg.norm(held.omega[-1])) > 5.0
    res = tilt_closure(feats, X_trk, Q, A_AX, np.zeros(3), match=_match, tol=0.02, voted=voted, smooth=1, reach=4)
    w = reach_weights(held.votes > 0, 4)
    assert np.allclose(res.omega, held.omega * w[:, None])
    assert np.all(res.omega[24:] == 0)  # 5 or more frames past the last measured one: the loop's own pose
    assert np.array_equal(apply_tilt(X_trk, res)[24:], X_trk[24:])
    assert np.allclose(res.omega[1:20], held.omega[1:20])  # measured frames keep their correction
    assert _errs(apply_tilt(X_trk, res)[:20], X_true[:20]).max() < 1.5


def test_reach_zero_is_the_closure_as_before():
    rng = np.random.default_rng(4)
    Q, X_true, X_trk, feats = _session(rng)
    a = tilt_closure(feats, X_trk, Q, A_AX, np.zeros(3), match=_match, tol=0.02)
    b = tilt_closure(feats, X_trk, Q, A_AX, np.zeros(3), match=_match, tol=0.02, reach=0)
    assert np.array_equal(a.omega, b.omega) and np.array_equal(a.votes, b.votes)


def test_config():
    assert TrackingConfig().spin_tilt_reach == 0
    assert TrackingConfig(spin_tilt_reach=15).spin_tilt_reach == 15
    for bad in (-1, 2.5, True, "15", None):
        with pytest.raises(ValueError):
            TrackingConfig(spin_tilt_reach=bad)
