"""A fall the loop loses: the landing carried by the turn about the base rim (lost_land; service.tracking.lying,
tracker._lost_landing)."""
from types import SimpleNamespace

import numpy as np
import pytest

from service.tracking import TrackingConfig
from service.tracking.lying import axial_gap, base_rim, rim_landing, topple_time
from service.tracking.tracker import Keyframe, _lost_landing, _model_from
from service.transforms import X_inv, make_X, so3_exp

TABLE = 0.0
R = 0.034
H = 0.2


def _bottle(rng, lo=0.0, hi=H, n=4000):
    """Surface points (n,3) in O and their normals of a cylinder of radius R standing with its base at height 0 and
    its axis along z through (0.01, -0.02), between heights lo and hi, seen over 200° of azimuth."""
    h = rng.uniform(lo, hi, n)
    phi = rng.uniform(-np.radians(100), np.radians(100), n)
    N = np.c_[np.cos(phi), np.sin(phi), np.zeros(n)]
    P = np.c_[R * N[:, 0] + 0.01, R * N[:, 1] - 0.02, h]
    return P + rng.normal(0, 0.0003, P.shape), N


def _box(rng, n=4000):
    """Points and normals of two sides of a 60 mm square prism 200 mm tall standing on the table, axis along z."""
    s = rng.uniform(-0.03, 0.03, n)
    h = rng.uniform(0.0, H, n)
    side = rng.random(n) < 0.5
    P = np.where(side[:, None], np.c_[np.full(n, 0.03), s, h], np.c_[s, np.full(n, 0.03), h])
    N = np.where(side[:, None], [1.0, 0, 0], [0, 1.0, 0])
    return P, N


def _tipped(theta_deg, base=np.array([0.01, -0.02, 0.0]), f=np.array([1.0, 0.0, 0.0])):
    """The standing pose (identity, O = W) turned about the base rim's point along f, on the table, by theta."""
    p = base + R * f
    k = np.cross([0.0, 0.0, 1.0], f)
    Rt = so3_exp(np.radians(theta_deg) * k)
    return make_X(Rt, p - Rt @ p)


def test_rim_landing_lays_the_axis_at_the_radius_above_the_pivot():
    a = np.array([0.0, 0.0, 1.0])
    b_O = np.array([0.01, -0.02, 0.0])
    X40 = _tipped(40.0)
    Xl = rim_landing(X40, a, b_O, R, TABLE)
    X90 = _tipped(90.0)
    assert np.allclose(Xl, X90, atol=1e-9)  # the same turn, completed
    w = Xl[:3, :3] @ a
    assert abs(w[2]) < 1e-9 and w[0] > 0.99  # horizontal, along the tipping direction
    bc = Xl[:3, :3] @ b_O + Xl[:3, 3]
    assert abs(bc[2] - (TABLE + R)) < 1e-9 and abs(bc[0] - (0.01 + R)) < 1e-9  # above the pivot at R
    # a fall pose 6 mm too high and 3 mm aside: the pivot is put on the table, the axis lies at R above it
    Xoff = X40.copy()
    Xoff[:3, 3] += [0.0, 0.003, 0.006]
    Xl2 = rim_landing(Xoff, a, b_O, R, TABLE)
    bc2 = Xl2[:3, :3] @ b_O + Xl2[:3, 3]
    assert abs(bc2[2] - (TABLE + R)) < 1e-9
    assert rim_landing(np.eye(4), a, b_O, R, TABLE) is None  # standing upright: no tipping direction


def test_axial_gap_counts_the_slide_along_the_axis_and_the_turn_not_the_spin():
    a = np.array([0.0, 0.0, 1.0])
    b_O = np.array([0.01, -0.02, 0.0])
    X = _tipped(90.0)
    w = X[:3, :3] @ a
    slid = X.copy()
    slid[:3, 3] += 0.07 * w + [0.0, 0.01, 0.0]
    deg, dist = axial_gap(slid, X, a, b_O)
    assert deg < 1e-6 and abs(dist - 0.07) < 1e-9
    spun = X @ make_X(so3_exp(np.radians(60) * a), np.zeros(3))  # about the axis through O's origin
    c = X[:3, :3] @ b_O + X[:3, 3]
    spun[:3, 3] += c - (spun[:3, :3] @ b_O + spun[:3, 3])  # about the axis line itself
    assert max(axial_gap(spun, X, a, b_O)) < 1e-6
    turned = make_X(so3_exp(np.radians(100) * np.array([0.0, 1.0, 0.0])), np.zeros(3)) @ X
    assert axial_gap(turned, X, a, b_O)[0] > 99.0


def test_base_rim_of_a_partly_seen_body():
    rng = np.random.default_rng(4)
    Q, _ = _bottle(rng, lo=0.12, hi=H)  # only the upper part modelled
    b_O, r = base_rim(Q, np.array([0.0, 0.0, 1.0]), 0.0)
    assert np.allclose(b_O, [0.01, -0.02, 0.0], atol=0.002) and abs(r - R) < 0.001


def test_topple_time():
    t40 = topple_time(np.radians(40), 3.0, R, H)
    assert 0.05 < t40 < 0.3
    assert topple_time(np.radians(40), 1.0, R, H) > t40  # a slower start lands later
    assert topple_time(np.radians(60), 3.0, R, H) < t40
    assert topple_time(np.radians(3), 0.05, R, H) == np.inf  # short of the balance tilt: it falls back
    assert topple_time(np.radians(95), 1.0, R, H) == 0.0


def _lost_fall(Q, N, X_reacq, n_lost=6):
    """A session-like stand-in, poses and keyframes: 20 frames standing (keyframes 0 and 10 with the model Q, N), a fall
    tracked from frame 20 to 25 turning 8°/frame about the base rim from 8° to 48°, lost for n_lost frames, re-acquired
    at frame i with the pose X_reacq. Returns (session, X, last, keyframes, frame observation, i)."""
    n = 26 + n_lost + 1
    X = np.tile(np.eye(4), (n, 1, 1))
    for j, th in zip(range(20, 26), np.arange(8.0, 49.0, 8.0)):
        X[j] = _tipped(th)
    i = 26 + n_lost
    X[i] = X_reacq
    kfs = [Keyframe(k, np.eye(4), Q, Q, N, np.zeros((0, 3)), None, np.zeros((0, 3))) for k in (0, 10)]
    kfs.append(Keyframe(22, X[22], Q[:100], Q[:100], N[:100], np.zeros((0, 3)), None, np.zeros((0, 3))))
    session = SimpleNamespace(table_height=TABLE, frame_times=np.arange(n) / 30.0)
    rng = np.random.default_rng(7)
    P_low, N_low = _bottle(rng, lo=0.0, hi=0.08, n=600)  # the lying frame shows the lower part
    Xt = _tipped(90.0)
    o = SimpleNamespace(P_W=P_low @ Xt[:3, :3].T + Xt[:3, 3], N_W=N_low @ Xt[:3, :3].T, kp_W=np.zeros((0, 3)),
                        desc=None)
    last = list(range(0, 26)) + [i]
    return session, X, last, kfs, o, i


def test_a_reacquisition_slid_along_the_axis_is_replaced_by_the_landing():
    rng = np.random.default_rng(5)
    Q, N = _bottle(rng, lo=0.12, hi=H)
    Xt = _tipped(90.0)
    slid = Xt.copy()
    slid[:3, 3] += 0.08 * (Xt[:3, :3] @ [0.0, 0.0, 1.0])  # the lower part laid along the modelled upper part
    session, X, last, kfs, o, i = _lost_fall(Q, N, slid)
    cfg = TrackingConfig(lost_land=True)
    log = []
    out = _lost_landing(session, i, o, X, last, kfs, None, log, cfg)
    assert out is not None and log[-1]["adopted"] and abs(log[-1]["dist"] - 0.08) < 0.01
    assert np.allclose(X[i], rim_landing(X[25], np.array([0, 0, 1.0]), np.array([0.01, -0.02, 0.0]),
                                         log[-1]["radius"], TABLE), atol=0.003)
    assert np.linalg.norm(X[i][:3, 3] - Xt[:3, 3]) < 0.003  # the true landing
    assert [kf.index for kf in kfs] == [0, 10, i]  # the fall's keyframe dropped, the landing frame added
    assert out[0].inlier_frac > 0.99  # the frame's points are the new keyframe's


def test_left_alone_near_the_landing_in_the_fall_or_for_a_box():
    rng = np.random.default_rng(6)
    Q, N = _bottle(rng, lo=0.12, hi=H)
    Xt = _tipped(90.0)
    near = Xt.copy()
    near[:3, 3] += 0.01 * (Xt[:3, :3] @ [0.0, 0.0, 1.0])
    session, X, last, kfs, o, i = _lost_fall(Q, N, near)
    log = []
    assert _lost_landing(session, i, o, X, last, kfs, None, log, TrackingConfig(lost_land=True)) is None
    assert not log[-1]["adopted"] and np.array_equal(X[i], near) and len(kfs) == 3
    # re-acquired one frame after the loss: a body tilted 48° at 8°/frame cannot have landed yet
    session, X, last, kfs, o, i = _lost_fall(Q, N, Xt @ make_X(np.eye(3), [0, 0, 0.08]), n_lost=0)
    log = []
    assert _lost_landing(session, i, o, X, last, kfs, None, log, TrackingConfig(lost_land=True)) is None and not log
    # a box: flat faces, not a body of revolution
    B, NB = _box(rng)
    session, X, last, kfs, o, i = _lost_fall(B, NB, Xt @ make_X(np.eye(3), [0, 0, 0.08]))
    log = []
    assert _lost_landing(session, i, o, X, last, kfs, None, log, TrackingConfig(lost_land=True)) is None and not log


@pytest.mark.parametrize("field,value", [("lost_land_tilt_deg", 0.0), ("lost_land_tilt_deg", 90.0),
                                         ("lost_land_deg", 0.0), ("lost_land_dist", -0.01), ("lost_land", 1)])
def test_bad_settings_refused(field, value):
    with pytest.raises(ValueError, match=field):
        TrackingConfig(**{field: value})
