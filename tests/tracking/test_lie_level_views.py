"""The straight stretch of a lying body of revolution from the lying views' own profile (``lie_level_views``,
service.tracking.lying.lying_views_stretch): a merged model smeared by lying views attached tilted has none about
the vertical of frame 0, the lying views about their own axis have it."""
import numpy as np
import pytest

from service.tracking import TrackingConfig
from service.tracking.lying import level_lying, lying_views_stretch, straight_stretch, axis_centre
from service.tracking.tracker import Keyframe, _lying_points
from service.transforms import so3_exp

from tests.tracking.test_lying import R_BODY, TABLE, _angle, _bottle, _poses


def _smeared(rng, tilt_deg=6.0, egg=False):
    """(merged model (M,3), lying views (M',3)) in O: the standing views see the bottle's top 70 mm only (an
    occluder hides the rest); the lying views see all of it, attached turned by ``tilt_deg`` about the x axis through
    the centroid."""
    Q = _bottle(rng, egg=egg)
    top = Q[Q[:, 2] > Q[:, 2].max() - (0.07 if not egg else 0.03)]
    ctr = Q.mean(0)
    L = (Q - ctr) @ so3_exp(np.array([np.radians(tilt_deg), 0.0, 0.0])).T + ctr
    return np.vstack([top, L]), L


def test_smeared_model_levelled_only_with_the_lying_views():
    rng = np.random.default_rng(4)
    M, L = _smeared(rng)
    z = np.array([0.0, 0.0, 1.0])
    assert not straight_stretch(M, z, axis_centre(M, z))[0]  # the merged profile is smeared
    found, radius = lying_views_stretch(L, z)
    assert found and abs(radius - R_BODY) < 0.0015
    true, bad = _poses(M, 4.5)
    out0, done0 = level_lying(bad, M, TABLE, z)  # lie_level alone: refused
    assert not done0.any() and np.array_equal(out0, bad)
    out, done = level_lying(bad, M, TABLE, z, Q_lying=L)
    assert not done[:25].any() and np.array_equal(out[:25], bad[:25])
    assert done[28:].all()
    assert _angle(bad[28:], true[28:]).min() > 4.4
    assert _angle(out[28:], true[28:]).max() < 0.05
    assert np.abs(out[28:, :3, 3] - true[28:, :3, 3]).max() < 0.002


def test_lying_views_refused():
    rng = np.random.default_rng(5)
    z = np.array([0.0, 0.0, 1.0])
    M, L = _smeared(rng, egg=True)  # an egg's lying views have no straight stretch
    assert not lying_views_stretch(L, z)[0]
    _, L30 = _smeared(rng, tilt_deg=30.0)  # views whose axis is far from the body's: not one body
    assert not lying_views_stretch(L30, z)[0]
    assert not lying_views_stretch(L[:100], z)[0]  # too few points


def test_lying_points_of_the_keyframes():
    cfg = TrackingConfig(lie_level_views=True)
    stand = np.eye(4)
    lie = np.eye(4)
    lie[:3, :3] = so3_exp(np.array([np.radians(80.0), 0.0, 0.0]))  # ẑ_O 10° above the horizontal
    e = np.zeros((0, 3))
    kfs = [Keyframe(0, stand, np.ones((3, 3)), e, e, e, None), Keyframe(5, lie, 2 * np.ones((4, 3)), e, e, e, None)]
    P = _lying_points(kfs, cfg)
    assert P.shape == (4, 3) and np.all(P == 2)
    assert _lying_points(kfs[:1], cfg).shape == (0, 3)


def test_bad_setting_refused():
    with pytest.raises(ValueError, match="lie_level_views"):
        TrackingConfig(lie_level_views=1)


def test_tracker_step_off_leaves_the_poses_as_lie_level():
    """``tracker._level_lying``: with ``lie_level_views`` off the lying keyframes are not read and the poses are
    ``lie_level``'s bit for bit (here: refused, unchanged); on, the lying frames are levelled."""
    from types import SimpleNamespace

    from service.tracking.tracker import _level_lying

    rng = np.random.default_rng(6)
    M, L = _smeared(rng)
    true, bad = _poses(M, 4.5)
    e = np.zeros((0, 3))
    lie = true[40].copy()  # a lying keyframe: its views L placed in O
    kfs = [Keyframe(0, true[0], M[:50], e, e, e, None), Keyframe(40, lie, L, e, e, e, None)]
    model = SimpleNamespace(Q=M)
    spin = SimpleNamespace(is_revolution=True, axis_O=np.array([0.0, 0.0, 1.0]))
    X_off = bad.copy()
    _level_lying(X_off, model, spin, TABLE, TrackingConfig(lie_level_views=False), kfs)
    assert np.array_equal(X_off, bad)
    X_on = bad.copy()
    _level_lying(X_on, model, spin, TABLE, TrackingConfig(lie_level_views=True), kfs)
    assert _angle(X_on[28:], true[28:]).max() < 0.05
