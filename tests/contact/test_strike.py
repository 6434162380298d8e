"""Strikes on a side the camera does not see: the measured sphere must bound the learned geometry there.

A box (half-extents 40 × 30 × 20 mm, 0.3 kg) rests on the table and is struck three times from −y by the robot's
sphere (0.45 m/s launches, 30 Hz, backward-difference velocities as the tracker gives them); at the first moving
frame the sphere touches the true −y face, before and after it is ≥ 15 mm away. The visible points cover every side
but −y, and the initial geometry (as the tracker's visible mesh on a hidden side) reaches 12 mm past the −y face.
Only the sphere contradicts that: with PLL's penetration weight (0.5) for the sphere contact too, the learned −y
support stays 7 mm or more out with the sphere inside it by as much; with the sphere contact's own weight
(``ContactConfig.w_pen_ee`` = 50; off by default, docs/contact.md) it comes back to the face.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from service.contact.fit import run
from service.contact.types import ContactConfig, ContactInputs
from service.session.types import Friction

HALF = np.array([0.04, 0.03, 0.02])
R_EE = 0.0195
DT = 1.0 / 30.0
MU = 0.3
G = 9.81


def strike_session(n_strikes: int = 3, rest: int = 12, v0: float = 0.45):
    """States (T,13) of the struck box and the sphere centres (T,3), velocities by backward differences."""
    y = [0.0]
    hit = []
    for _ in range(n_strikes):
        y += [y[-1]] * rest
        hit.append(len(y))  # frame index of the first moving frame (sphere touching the −y face)
        v = v0
        while v > 0:
            y.append(y[-1] + DT * v)
            v -= MU * G * DT
    y += [y[-1]] * rest
    T = len(y)
    p = np.zeros((T, 3))
    p[:, 1] = y
    p[:, 2] = HALF[2]
    X = np.zeros((T, 13))
    X[:, 0] = 1.0
    X[:, 4:7] = p
    X[1:, 10:13] = np.diff(p, axis=0) / DT
    ee = np.zeros((T, 3))
    ee[:, 2] = HALF[2]
    face = p[:, 1] - HALF[1] - R_EE  # sphere centre touching the −y face
    ee[:, 1] = face - 0.05  # far while the box rests
    for h in hit:
        for j, off in ((-2, 0.034), (-1, 0.017), (0, 0.0), (1, 0.0)):
            ee[h + j, 1] = face[h] - off  # approach at ~0.5 m/s, touch, stop (the box slides away)
        ee[h + 2:h + 6, 1] = face[h] - 0.015 * np.arange(1, 5)
    ve = np.zeros_like(ee)
    ve[1:] = np.diff(ee, axis=0) / DT
    ve[0] = ve[1]
    return X, ee, ve


def box_points(half, n=12, faces=("+x", "-x", "+y", "-y", "+z", "-z")):
    g = np.linspace(-1, 1, n)
    a, b = np.meshgrid(g, g)
    a, b = a.ravel(), b.ravel()
    out = []
    for f in faces:
        ax = "xyz".index(f[1])
        s = 1.0 if f[0] == "+" else -1.0
        o = [i for i in range(3) if i != ax]
        P = np.zeros((len(a), 3))
        P[:, ax] = s * half[ax]
        P[:, o[0]] = a * half[o[0]]
        P[:, o[1]] = b * half[o[1]]
        out.append(P)
    return np.concatenate(out)


def _inputs():
    X, ee, ve = strike_session()
    vis = box_points(HALF, faces=("+x", "-x", "+y", "+z"))  # the camera sees neither −y nor the bottom
    init = box_points(HALF, n=6)
    init[:, 1] = np.where(init[:, 1] < -HALF[1] + 1e-9, -HALF[1] - 0.012, init[:, 1])  # hidden side 12 mm out
    return ContactInputs(dt=DT, states=(X,), ee_p_W=(ee,), ee_v_W=(ve,), ee_radius=R_EE, table_height=0.0,
                         friction=Friction(MU, 0.15), mass=0.3, mass_declared=True, visible_points_O=vis,
                         init_vertices_O=init)


def _support_minus_y(out) -> float:
    return float(-np.asarray(out.physible_mesh.vertices)[:, 1].min())


@pytest.fixture(scope="module")
def inputs():
    return _inputs()


def _cfg(**kw) -> ContactConfig:
    # the CoM fixed: three strikes along one line do not fix it, and the realizability term would let a drifting
    # CoM widen the shape (what is tested here is the geometry on the struck side)
    return dataclasses.replace(ContactConfig.fast(), epochs=40, min_epochs=40, learn_com=False, **kw)


def test_sphere_penetration_pulls_the_hidden_side_back(inputs):
    out = run(inputs, _cfg(w_pen_ee=50.0))
    h = _support_minus_y(out)
    assert abs(h - HALF[1]) < 0.003, f"−y support {h * 1e3:.1f} mm, true {HALF[1] * 1e3:.0f} mm"
    ee = out.residuals.impulse_ee > 0.05
    assert ee.sum() >= 3  # the strikes are explained by the sphere
    assert out.residuals.phi_ee[ee].min() > -0.003


def test_pll_penetration_weight_leaves_the_hidden_side_out(inputs):
    """The same data with the sphere contact weighted like the table's (PLL's 0.5, the default): the −y side stays
    out."""
    assert ContactConfig().w_pen_ee is None and ContactConfig().w_pen == 0.5
    out = run(inputs, _cfg())
    h = _support_minus_y(out)
    assert h - HALF[1] > 0.004, f"−y support {h * 1e3:.1f} mm"


def test_w_pen_ee_validated():
    with pytest.raises(ValueError, match="w_pen_ee"):
        ContactConfig(w_pen_ee=-1.0)
