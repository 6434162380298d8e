"""Support closure of the visible SDF (``visible.carved_init(..., support_O=...)``, ``sdf_support_hull``): a
triangular prism lying on the table, seen from one side and above with an occluder hiding its lower part. The hull
of the seen points (the upper part of the front face and of one end) closes the hidden lower part as air; with the
seen points' feet on the table it is object, and what lies outside the prism stays outside."""

import numpy as np
import pytest

from service.sdf import RaySet, SdfConfig, fit_sdf, sdf_query
from service.tracking.tracker import FreeSpace
from service.tracking.visible import below_table_halfspace, carved_init, support_feet
from service.transforms import make_X

SIDE, LENGTH = 0.065, 0.12
HEIGHT = SIDE * np.sqrt(3) / 2
W, H = 120, 90
K = np.array([[150.0, 0, W / 2], [0, 150.0, H / 2], [0, 0, 1]])


def _halfspaces_prism():
    """(F,4) rows (n, b) with n·p + b <= 0 inside: ridge along x over y = 0, base on z = 0 (O = W)."""
    s = np.sqrt(3) / 2
    return np.array([[0, 0, -1, 0], [0, s, 0.5, -s * SIDE / 2], [0, -s, 0.5, -s * SIDE / 2],
                     [1, 0, 0, -LENGTH / 2], [-1, 0, 0, -LENGTH / 2]], float)


def _halfspaces_box(lo, hi):
    return np.array([[1, 0, 0, -hi[0]], [-1, 0, 0, lo[0]], [0, 1, 0, -hi[1]], [0, -1, 0, lo[1]],
                     [0, 0, 1, -hi[2]], [0, 0, -1, lo[2]]], float)


def _hit(o, d, planes):
    """Entry parameter (R,) of rays o + t·d into a convex polytope (inf: missed)."""
    t0, t1 = np.zeros(len(d)), np.full(len(d), np.inf)
    for n, b in zip(planes[:, :3], planes[:, 3]):
        num, den = -(o @ n + b), d @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = num / den
        enter, leave = den < 0, den > 0
        t0 = np.where(enter, np.maximum(t0, t), t0)
        t1 = np.where(leave, np.minimum(t1, t), t1)
        t1 = np.where((den == 0) & (num < 0), -np.inf, t1)
    return np.where(t0 <= t1, t0, np.inf)


def _scene():
    """Camera 40° above the table on the front (+y) side and a little to +x (it sees the front face and the +x
    end); a box in front of the prism hides its lower part."""
    c = np.array([0.12, 0.42, 0.36])
    f = -c / np.linalg.norm(c)  # optical axis to the origin
    x = np.cross(f, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(f, x)
    X_WC = make_X(np.stack([x, y, f], 1), c)
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    d_C = np.stack([(u.ravel() - K[0, 2]) / K[0, 0], (v.ravel() - K[1, 2]) / K[1, 1], np.ones(W * H)], 1)
    d_W = d_C @ X_WC[:3, :3].T  # camera-z component 1
    o = np.tile(c, (len(d_W), 1))
    t_obj = _hit(o, d_W, _halfspaces_prism())
    t_occ = _hit(o, d_W, _halfspaces_box([-0.2, 0.04, 0.0], [0.2, 0.05, 0.035]))
    t_tab = np.where(d_W[:, 2] < 0, -c[2] / np.where(d_W[:, 2] < 0, d_W[:, 2], -1), np.inf)
    t = np.minimum(np.minimum(t_obj, t_occ), t_tab)
    depth = t.reshape(H, W).astype(np.float32)  # camera z = t (unit camera-z directions)
    seen = np.isfinite(t_obj) & (t_obj <= np.minimum(t_occ, t_tab))
    rng = np.random.default_rng(0)
    z = t[seen] + rng.normal(0, 0.0005, seen.sum())
    rays = RaySet(o[seen], d_W[seen], z, np.full(seen.sum(), np.inf), np.ones(seen.sum()))
    fs = FreeSpace(K, X_WC, margin=0.005, px=1)
    fs.add(0, depth, np.eye(4))
    return rays, fs


def test_feet_lie_on_the_table_below_the_points():
    hs = below_table_halfspace(np.eye(4), 0.0)
    P = np.array([[0.01, 0.02, 0.05], [0.0, 0.0, 0.0], [0.03, -0.01, -0.02]])
    assert np.allclose(support_feet(P, hs), [[0.01, 0.02, 0.0], [0.0, 0.0, 0.0], [0.03, -0.01, -0.02]])
    X = np.eye(4)
    X[:3, 3] = [0.1, 0.2, 0.3]  # O above the table: the plane z_W = 0 is z_O = −0.3
    assert np.allclose(support_feet(np.array([[0.0, 0.0, 0.1]]), below_table_halfspace(X, 0.0)), [[0, 0, -0.3]])


def test_support_closes_the_hidden_lower_part_and_stays_inside():
    rays, fs = _scene()
    P = rays.surface_points_O
    assert P[P[:, 1] > 0.01, 2].min() > 0.012  # the occluder hides the lower part of the front face
    cfg = SdfConfig(resolution=40, pad=0.02)
    hs = below_table_halfspace(np.eye(4), 0.0)
    hidden = np.array([[0.0, 0.0, 0.006], [0.0, 0.015, 0.006], [-0.03, 0.015, 0.006]])  # inside, low, never seen
    outside = np.array([[0.0, 0.036, 0.01], [0.0, 0.03, 0.03], [0.0, -0.045, 0.01], [0.075, 0.0, 0.01]])
    plain = carved_init(rays, cfg, fs, 0.005)
    assert np.all(sdf_query(plain, hidden) > 0), sdf_query(plain, hidden)  # the seen points' hull: air
    g = carved_init(rays, cfg, fs, 0.005, support_O=hs)
    assert np.all(sdf_query(g, hidden) < 0), sdf_query(g, hidden)
    assert np.all(sdf_query(g, outside) > 0), sdf_query(g, outside)
    # the fit keeps the closure where no ray says otherwise
    fit = fit_sdf(rays, SdfConfig(resolution=40, pad=0.02, steps=60, rays_per_step=512, samples_near=8,
                                  samples_far=8, w_empty=300.0), init=g, halfspace_O=hs)
    assert np.all(sdf_query(fit, hidden) < 0), sdf_query(fit, hidden)
    assert np.all(sdf_query(fit, outside) > 0), sdf_query(fit, outside)


def test_support_hull_acts_only_with_the_table_plane():
    from service.tracking import TrackingConfig

    cfg = TrackingConfig()
    assert cfg.sdf_support_hull and cfg.below_table_outside
    TrackingConfig(below_table_outside=False)  # valid: no plane, no closure (tracking.run passes no support plane)
