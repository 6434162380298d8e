"""Free-body dynamics (method-notes §2.6) against closed-form free flight, with an offset CoM."""

import numpy as np

from service.contact.inertia import solid_box_inertia
from service.contact.simulate import Body, box_vertices, simulate
from service.transforms import quat_to_mat, rotvec_to_quat


def test_free_flight_com_parabola_and_angular_momentum():
    c = np.array([0.01, -0.005, 0.008])
    I = solid_box_inertia([0.04, 0.03, 0.02], 0.3)
    body = Body(box_vertices([0.04, 0.03, 0.02]), 0.3, c, I, 0.3)
    x0 = np.zeros(13)
    x0[0:4] = rotvec_to_quat(np.array([0.3, -0.2, 0.5]))
    x0[4:7] = [0.0, 0.0, 5.0]  # far above the table
    x0[7:10] = [3.0, -2.0, 4.0]
    x0[10:13] = [0.5, 0.2, 1.0]
    dt, n = 2e-3, 80
    X = simulate(body, x0[None], n, dt)[0]
    R = quat_to_mat(X[:, 0:4])
    com_W = X[:, 4:7] + (R @ c)
    # CoM velocity from the generalised velocity: v_c = v_o + R(ω × c)
    vc0 = X[1, 10:13] + R[1] @ np.cross(X[1, 7:10], c)
    t = dt * np.arange(n + 1)
    pred = com_W[1] + np.outer(t - t[1], vc0) + 0.5 * np.outer((t - t[1]) ** 2, [0, 0, -9.81])
    # semi-implicit Euler lags the exact parabola by ½ g dt (t − t₁) at most
    assert np.abs(com_W[1:] - pred[1:]).max() < 0.5 * 9.81 * dt * t[-1] + 1e-6
    assert np.abs(com_W[1:, :2] - pred[1:, :2]).max() < 5e-5
    # angular momentum about the CoM in world axes is conserved
    L = np.einsum("tij,jk,tk->ti", R, I, X[:, 7:10])
    assert np.abs(L[1:] - L[1]).max() < 3e-3 * np.abs(L[1]).max()


def test_box_comes_to_rest_on_the_table():
    h = np.array([0.04, 0.03, 0.02])
    body = Body(box_vertices(h), 0.3, np.zeros(3), solid_box_inertia(h, 0.3), 0.4)
    x0 = np.zeros(13)
    x0[0] = 1.0
    x0[6] = 0.05
    x0[10] = 0.5
    X = simulate(body, x0[None], 50, 0.01)[0]
    assert abs(X[-1, 6] - 0.02) < 1e-3  # resting on its largest face
    assert np.linalg.norm(X[-1, 7:13]) < 1e-2
    assert X[-1, 4] > 0.005  # it slid before stopping
