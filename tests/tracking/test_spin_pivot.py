"""The tilts of a pivot without spin (service.tracking.fall: ``pivot_runs``, ``pivot_bridge``; ``spin_pivot_deg``):
a body of revolution standing at frame 0 is tilted 12° onto the rim of its base and back (frames 20-50) and turns
2° about its axis meanwhile (friction); the tracked poses add a false spin of up to 10° in the tilt that goes away
when it stands again. With a correction measured only while upright (the texture) or none (no texture), the bridge
brings every frame of the tilt within 0.6° of the truth; a topple (no way back), a small tilt and a body lying at frame
0 are not pivots; a correction that already follows the tilt is kept; a tilt still on at the last frame takes the
no-twist increments alone."""

from __future__ import annotations

import numpy as np
import pytest

from service.tracking.fall import pivot_bridge, pivot_runs
from service.tracking.spin import SpinResult, spin_matrix
from service.tracking.types import TrackingConfig
from service.transforms import make_X, rotation_angle, so3_exp

N_FR, T0, T1 = 70, 20, 50
A, C = np.array([0.0, 0.0, 1.0]), np.zeros(3)  # axis z_O through the origin of O


def _poses(tilt_deg: np.ndarray, spin_deg: np.ndarray) -> np.ndarray:
    """Poses of a body standing upright (z_O vertical) tilted about the x axis of W and turned about its axis."""
    return np.stack([make_X(so3_exp(np.array([np.radians(t), 0.0, 0.0])), np.array([0.5, 0.0, 0.1])) @
                     spin_matrix(A, C, np.radians(s)) for t, s in zip(tilt_deg, spin_deg)])


def _pivot():
    """True poses, tracked poses and the correction each tracked pose needs (X_trk S(need) = X_true)."""
    i = np.arange(N_FR)
    phase = np.clip((i - T0) / (T1 - T0), 0, 1)
    tilt = 12.0 * np.sin(np.pi * phase)
    spin = 2.0 * phase  # the real turn (friction), done along the tilt
    false = 10.0 * np.sin(np.pi * phase) ** 2  # the tracker's spin in the tilt, gone once upright
    X_true = _poses(tilt, spin)
    need = np.radians(-false + 0.0 * i)
    X_trk = np.stack([X @ spin_matrix(A, C, -e) for X, e in zip(X_true, need)])
    return X_true, X_trk, need


def _err_deg(X_true: np.ndarray, X: np.ndarray) -> np.ndarray:
    return np.degrees(rotation_angle(np.einsum("nji,njk->nik", X_true[:, :3, :3], X[:, :3, :3])))


def test_pivot_runs_finds_the_tilt_and_not_a_topple_or_a_small_tilt():
    _, X_trk, _ = _pivot()
    (s, e), = pivot_runs(X_trk, A, 5.0)
    assert T0 < s <= T0 + 3 and T1 - 3 <= e <= T1  # the tilted frames, upright frames outside
    i = np.arange(N_FR)
    topple = _poses(np.clip((i - T0) * 4.5, 0, 90), np.zeros(N_FR))  # lies from frame 40 on: no way back
    assert pivot_runs(topple, A, 5.0) == []
    small = _poses(3.0 * np.sin(np.pi * np.clip((i - T0) / 30, 0, 1)), np.zeros(N_FR))
    assert pivot_runs(small, A, 5.0) == []
    assert len(pivot_runs(small, A, 2.0)) == 1


def test_bridge_removes_the_false_spin_of_the_tilt():
    X_true, X_trk, need = _pivot()
    theta = np.where(np.arange(N_FR) < T0, 0.0, need)  # the texture: right while upright ...
    theta[T0:T1] = need[T0]  # ... and lost in the tilt (held)
    before = _err_deg(X_true, np.stack([X @ spin_matrix(A, C, t) for X, t in zip(X_trk, theta)]))
    assert before.max() > 8.0
    tilts = pivot_runs(X_trk, A, 5.0)
    out, used = pivot_bridge(theta, X_trk, A, tilts, 3.0)
    after = _err_deg(X_true, np.stack([X @ spin_matrix(A, C, t) for X, t in zip(X_trk, out)]))
    assert after.max() < 0.6
    s, e = tilts[0]
    assert used[s:e].all() and not used[:s].any() and not used[e:].any()
    assert np.array_equal(out[:s], theta[:s]) and np.array_equal(out[e:], theta[e:])  # the upright frames kept


def test_a_correction_that_follows_the_tilt_is_kept():
    X_true, X_trk, need = _pivot()
    tilts = pivot_runs(X_trk, A, 5.0)
    theta = need + np.radians(0.5) * np.sin(np.arange(N_FR))  # the texture followed (within 0.5°)
    out, used = pivot_bridge(theta, X_trk, A, tilts, 3.0)
    assert not used.any() and np.array_equal(out, theta)
    out, used = pivot_bridge(theta, X_trk, A, tilts, 0.1)  # a tight tolerance: bridged all the same
    assert used.any() and _err_deg(X_true, np.stack([X @ spin_matrix(A, C, t) for X, t in zip(X_trk, out)])).max() < 0.6


def test_a_tilt_still_on_at_the_last_frame_and_a_lying_body():
    X_true, X_trk, need = _pivot()
    cut = 40  # the session ends in the tilt: no upright end, no twist from the frame before it
    (s, e), = pivot_runs(X_trk[:cut], A, 5.0)
    assert e == cut
    theta = np.zeros(cut)
    out, used = pivot_bridge(theta, X_trk[:cut], A, [(s, e)], 3.0)
    after = _err_deg(X_true[:cut], np.stack([X @ spin_matrix(A, C, t) for X, t in zip(X_trk[:cut], out)]))
    assert used[s:].all() and after.max() < 1.8  # the friction's 2° along the tilt is what is left (2·20/30 by 40)
    lying = np.stack([X @ make_X(so3_exp(np.array([0.0, np.pi / 2, 0.0])), np.zeros(3)) for X in X_trk])
    assert pivot_runs(lying, np.array([0.0, 1.0, 0.0]), 5.0) == []  # the axis y_O lies at frame 0: a roll, not a pivot
    assert len(pivot_runs(lying, np.array([1.0, 0.0, 0.0]), 5.0)) == 1  # x_O stands there (R_y(90°) x = -z)


def test_spin_pivot_bridges_a_textureless_body_and_leaves_a_rejected_correction_alone():
    from service.tracking.tracker import _spin_pivot

    X_true, X_trk, need = _pivot()
    cfg = TrackingConfig(spin_pivot_deg=5.0)
    theta = np.zeros(N_FR)
    for res in (SpinResult(True, 0.01, A, C, theta, np.zeros(N_FR, int), True, rejected=True),
                SpinResult(False, 0.5, np.zeros(3), np.zeros(3), theta, np.zeros(N_FR, int), False)):
        assert _spin_pivot(res, X_trk, cfg) is res
    for observable in (True, False):  # votes or none: the physics does not need the print
        res = SpinResult(True, 0.01, A, C, theta, np.zeros(N_FR, int), observable)
        out = _spin_pivot(res, X_trk, cfg)
        assert out is not res and out.observable == observable
        after = _err_deg(X_true, np.stack([X @ spin_matrix(A, C, t) for X, t in zip(X_trk, out.theta)]))
        assert after.max() < 0.6  # the false spin of the tilt taken out
    assert _spin_pivot(res, X_trk, TrackingConfig(spin_pivot_deg=15.0)) is res  # a 12° tilt is not one of 15°


def test_config_refuses_bad_pivot_settings():
    assert TrackingConfig().spin_pivot_deg == 5.0  # on by default (0: off, the previous outputs)
    TrackingConfig(spin_pivot_deg=0.0)
    for bad in (-1.0, 45.0, float("nan")):
        with pytest.raises(ValueError, match="spin_pivot_deg"):
            TrackingConfig(spin_pivot_deg=bad)
