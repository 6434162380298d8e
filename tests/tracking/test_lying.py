"""A lying body of revolution gets its axis parallel to the table (service.tracking.lying)."""
import numpy as np
import pytest

from service.tracking import TrackingConfig
from service.tracking.lying import axis_centre, level_lying, straight_stretch
from service.transforms import so3_exp

TABLE = 0.0
R_BODY = 0.034


def _bottle(rng, egg=False):
    """Surface points (M,3) in O of a bottle standing on its base with the axis along z through (0.01, -0.02):
    a 130 mm cylinder of radius 34 mm, a 40 mm shoulder and a 30 mm neck; seen over 200° of azimuth. ``egg``: a
    prolate spheroid (semi-axes 28 and 21 mm) instead."""
    h = rng.uniform(0.0, 0.2 if not egg else 0.056, 4000)
    if egg:
        rho = 0.021 * np.sqrt(np.clip(1 - ((h - 0.028) / 0.028) ** 2, 0, 1))
    else:
        rho = np.where(h < 0.13, R_BODY, np.where(h < 0.17, R_BODY - (h - 0.13) / 0.04 * 0.02, 0.014))
    phi = rng.uniform(-np.radians(100), np.radians(100), len(h))
    P = np.c_[rho * np.cos(phi) + 0.01, rho * np.sin(phi) - 0.02, h - 0.08]
    return P + rng.normal(0, 0.0005, P.shape)


def _poses(Q, err_deg):
    """60 frames: 20 standing (frame 0 identity, on the table), 5 tipping (axis from 90° to 15° above the horizontal),
    35 lying on the table with the axis turned by ``err_deg`` about the horizontal through the centroid's axis point;
    the true poses and the erroneous ones (N,4,4)."""
    zmin = Q[:, 2].min()
    X0 = np.eye(4)
    X0[2, 3] = TABLE - zmin  # the base on the table
    true, bad = [X0.copy() for _ in range(20)], [X0.copy() for _ in range(20)]
    for k, el in enumerate(np.linspace(75, 15, 5)):
        X = np.eye(4)
        X[:3, :3] = so3_exp(np.array([np.radians(90 - el), 0, 0]))
        X[:3, 3] = [0.0, 0.0, 0.15]
        true.append(X)
        bad.append(X.copy())
    p_O = np.array([0.01, -0.02, Q[:, 2].mean()])
    for k in range(35):
        X = np.eye(4)
        X[:3, :3] = so3_exp(np.array([np.radians(-90), 0, 0])) @ so3_exp(np.array([0, 0, 0.02 * k]))  # rolling
        c = X[:3, :3] @ p_O
        X[:3, 3] = np.array([0.002 * k, 0.0, TABLE + R_BODY]) - c  # the axis at the body's radius above the table
        true.append(X)
        p = X[:3, :3] @ p_O + X[:3, 3]
        aW = X[:3, :3] @ np.array([0, 0, 1.0])
        u = np.cross(aW, [0, 0, 1.0])
        Rd = so3_exp(np.radians(err_deg) * u / np.linalg.norm(u))
        Y = X.copy()
        Y[:3, :3] = Rd @ X[:3, :3]
        Y[:3, 3] = p + Rd @ (X[:3, 3] - p)
        bad.append(Y)
    return np.array(true), np.array(bad)


def _angle(A, B):
    R = np.einsum("nji,njk->nik", A[:, :3, :3], B[:, :3, :3])
    return np.degrees(np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1)))


def test_profile_of_a_bottle_and_of_an_egg():
    rng = np.random.default_rng(1)
    Q = _bottle(rng)
    a = np.array([0, 0, 1.0])
    c = axis_centre(Q, a)
    assert np.allclose(c[:2], [0.01, -0.02], atol=0.001)
    found, length, radius = straight_stretch(Q, a, c)
    assert found and length > 0.11 and abs(radius - R_BODY) < 0.001
    E = _bottle(rng, egg=True)
    assert not straight_stretch(E, a, axis_centre(E, a))[0]


def test_lying_frames_levelled_others_kept():
    rng = np.random.default_rng(2)
    Q = _bottle(rng)
    true, bad = _poses(Q, 4.5)
    out, done = level_lying(bad, Q, TABLE, np.array([0.02, 0.03, 1.0]))
    assert not done[:25].any() and np.array_equal(out[:25], bad[:25])  # standing and tipping frames kept
    assert done[28:].all()  # lying (the first 3 have a tipping frame among their neighbours)
    assert _angle(bad[25:], true[25:]).min() > 4.4
    assert _angle(out[28:], true[28:]).max() < 0.05
    assert np.abs(out[28:, :3, 3] - true[28:, :3, 3]).max() < 1e-4  # turned about the centroid's axis point


def test_left_alone_when_not_applicable():
    rng = np.random.default_rng(3)
    Q = _bottle(rng)
    _, bad = _poses(Q, 4.5)
    # the found axis far from the vertical of frame 0: the body did not stand on its base
    out, done = level_lying(bad, Q, TABLE, np.array([1.0, 0.0, 0.3]))
    assert not done.any() and np.array_equal(out, bad)
    # the table 5 cm lower: the body does not lie on it
    out, done = level_lying(bad, Q, TABLE - 0.05, np.array([0, 0, 1.0]))
    assert not done.any()
    # an error above the cap is not corrected
    _, bad12 = _poses(Q, 12.0)
    out, done = level_lying(bad12, Q, TABLE, np.array([0, 0, 1.0]), max_deg=10.0)
    assert not done.any()
    # an egg has no straight stretch
    E = _bottle(rng, egg=True)
    out, done = level_lying(bad, E, TABLE, np.array([0, 0, 1.0]))
    assert not done.any()


@pytest.mark.parametrize("field,value", [("lie_level_deg", 0.0), ("lie_level_max_deg", 90.0),
                                         ("lie_level_stand_deg", -1.0), ("lie_level_margin", -0.01),
                                         ("lie_level", "yes")])
def test_bad_settings_refused(field, value):
    with pytest.raises(ValueError, match=field):
        TrackingConfig(**{field: value})
