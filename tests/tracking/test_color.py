"""Coloured registration along the shape's weak directions (service.tracking.geometry.color_gradients,
icp(w_color=...)): a textured cylinder rolled about its axis keeps its point-to-plane residuals, its texture
does not; the colour term must recover the roll, and on a box (no weak direction) it must not enter at all."""

import numpy as np
from scipy.spatial import cKDTree

from service.tracking.geometry import color_gradients, icp
from service.transforms import make_X, pose_errors, so3_exp
from tests.tracking.test_degeneracy import _box, _cylinder, _visible


def _tex(P):
    """Intensity of a body point (texture fixed to the body): stripes around the axis and along it."""
    th = np.arctan2(P[:, 2], P[:, 1])
    return 0.5 + 0.25 * np.sin(6 * th) + 0.15 * np.cos(60 * P[:, 0])


def _register(P_O, N_O, X_true, X_start, noise, rng, **kw):
    cam_W = np.array([0.8, 0.0, 0.6])
    P_W = P_O @ X_true[:3, :3].T + X_true[:3, 3]
    N_W = N_O @ X_true[:3, :3].T
    vis = _visible(P_W, N_W, cam_W)
    Pw = P_W[vis] + 0.0005 * rng.normal(size=(vis.sum(), 3))
    c = _tex(P_O[vis]) + noise * rng.normal(size=vis.sum())
    tree = cKDTree(P_O)
    C = _tex(P_O)
    G = color_gradients(P_O, N_O, C, tree)
    return icp(Pw, X_start, tree, P_O, N_O, C_src=c, C_model=C, G_model=G, iters=15, dist0=0.02, dist_min=0.004,
               **kw)


def test_color_gradients_are_tangent_and_match_the_texture():
    rng = np.random.default_rng(0)
    P, N = _cylinder(rng, n=6000)
    side = np.abs(P[:, 0]) < 0.09
    G = color_gradients(P, N, _tex(P), cKDTree(P))
    assert np.abs((G * N).sum(1)).max() < 1e-6
    # analytic gradient on the side: ∂C/∂θ / r along the circumference, ∂C/∂x along the axis
    th = np.arctan2(P[:, 2], P[:, 1])
    t_hat = np.c_[np.zeros(len(P)), -np.sin(th), np.cos(th)]
    g_true = (0.25 * 6 * np.cos(6 * th) / 0.035)[:, None] * t_hat + (-0.15 * 60 * np.sin(60 * P[:, 0]))[:, None] * [1, 0, 0]
    err = np.linalg.norm(G[side] - g_true[side], axis=1)
    assert np.median(err) < 0.2 * np.median(np.linalg.norm(g_true[side], axis=1)), np.median(err)


def test_color_recovers_the_roll_of_a_textured_cylinder():
    rng = np.random.default_rng(1)
    P, N = _cylinder(rng, n=6000)
    X_true = make_X(so3_exp([0.3, 0.0, 0.0]), [0.5, 0.0, 0.1])
    X_start = X_true @ make_X(so3_exp([np.radians(8), 0, 0]), [0, 0, 0])  # 8° more roll about the axis
    r0 = _register(P, N, X_true, X_start, 0.02, rng, w_color=0.0)
    r1 = _register(P, N, X_true, X_start, 0.02, rng, w_color=0.01)
    _, e0 = pose_errors(r0.X_WO[None], X_true[None])
    et, e1 = pose_errors(r1.X_WO[None], X_true[None])
    assert np.degrees(e0[0]) > 4.0, np.degrees(e0)  # geometry alone cannot see the roll
    assert np.degrees(e1[0]) < 1.0 and et[0] < 0.002, (np.degrees(e1), et)


def test_color_does_not_enter_a_well_conditioned_fit():
    rng = np.random.default_rng(2)
    P, N = _box(rng)
    X_true = make_X(so3_exp([0.1, -0.2, 0.3]), [0.5, 0.0, 0.1])
    X_start = X_true @ make_X(so3_exp([0.02, 0.01, -0.02]), [0.003, -0.002, 0.002])
    ra = _register(P, N, X_true, X_start, 0.3, np.random.default_rng(3), w_color=0.0)
    rb = _register(P, N, X_true, X_start, 0.3, np.random.default_rng(3), w_color=0.01)  # very noisy colour
    assert np.allclose(ra.X_WO, rb.X_WO, atol=1e-12)


def test_chromaticity_ignores_lambert_shading():
    from service.tracking.tracker import point_colors

    rng = np.random.default_rng(4)
    rgb = rng.integers(40, 200, (24, 32, 3)).astype(np.uint8)
    shaded = np.round(rgb * 0.6).astype(np.uint8)  # the same surface turned away from the light
    u, v = rng.integers(4, 28, 50), rng.integers(4, 20, 50)
    a, b = point_colors(rgb, u, v, "chroma", 0.0), point_colors(shaded, u, v, "chroma", 0.0)
    assert a.shape == (50, 2) and np.abs(a - b).max() < 0.01
    ga, gb = point_colors(rgb, u, v, "gray", 0.0), point_colors(shaded, u, v, "gray", 0.0)
    assert np.abs(ga - gb).mean() > 0.1  # luma follows the shading


def test_rotation_only_map_drops_the_sliding_of_a_plane():
    from service.tracking.geometry import degenerate_map

    rng = np.random.default_rng(5)
    P = np.c_[rng.uniform(-0.05, 0.05, (500, 2)), np.zeros(500)]
    N = np.tile([0.0, 0.0, 1.0], (500, 1))
    J = np.hstack([np.cross(P, N), N])
    M = degenerate_map(J.T @ J, 500.0, P, 0.1)
    Mr = degenerate_map(J.T @ J, 500.0, P, 0.1, rot_only=True)
    slide, spin = np.array([0, 0, 0, 1.0, 0, 0]), np.array([0, 0, 1.0, 0, 0, 0])
    assert np.linalg.norm(M @ slide) > 0.9 and np.linalg.norm(Mr @ slide) < 1e-9
    assert np.linalg.norm(Mr @ spin) > 0.9  # the turn about the normal stays weak
