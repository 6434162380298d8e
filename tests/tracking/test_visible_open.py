"""Support closure over a cavity (``visible.carved_init(..., open_dilate=...)``, ``sdf_support_open``): a cup on
the table seen from one side and above, an occluder hiding the lower part of its near wall. The camera looks into
the mouth and sees the far inner wall and part of the floor; the cavity behind the near wall is seen by no ray.
The support closure (hull of the seen points and their feet on the table) fills that hidden cavity; the column test
leaves it as the hull of the seen points has it, and keeps the closure under the rim (the near wall)."""

import numpy as np

from service.sdf import RaySet, SdfConfig, sdf_query
from service.sdf.fit import hull_sdf
from service.tracking.tracker import FreeSpace
from service.tracking.visible import below_table_halfspace, carved_init, open_columns
from service.transforms import make_X

W, H = 160, 120
K = np.array([[220.0, 0, W / 2], [0, 220.0, H / 2], [0, 0, 1]])
OUT = (np.array([-0.03, -0.03, 0.0]), np.array([0.03, 0.03, 0.06]))  # cup: outer box, walls and floor 6 mm
INN = (np.array([-0.024, -0.024, 0.006]), np.array([0.024, 0.024, 0.08]))  # cavity, open at the top
OCC = (np.array([-0.2, 0.045, 0.0]), np.array([0.2, 0.055, 0.04]))  # occluder in front of the near (+y) wall


def _box(o, d, lo, hi):
    """Entry and exit parameters (R,) of rays o + t·d through the box [lo, hi] (entry > exit: missed)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / np.where(np.abs(d) < 1e-12, 1e-12, d)
        t1, t2 = (lo - o) * inv, (hi - o) * inv
    return np.maximum(np.minimum(t1, t2).max(1), 0.0), np.maximum(t1, t2).min(1)


def _scene():
    c = np.array([0.0, 0.30, 0.26])
    f = np.array([0.0, 0.0, 0.02]) - c
    f /= np.linalg.norm(f)
    x = np.cross(f, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    X_WC = make_X(np.stack([x, np.cross(f, x), f], 1), c)
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    d_W = np.stack([(u.ravel() - K[0, 2]) / K[0, 0], (v.ravel() - K[1, 2]) / K[1, 1], np.ones(W * H)], 1) @ X_WC[:3, :3].T
    o = np.tile(c, (len(d_W), 1))
    oi, oo = _box(o, d_W, *OUT)
    ii, io = _box(o, d_W, *INN)
    hit_out = oi <= oo
    in_mouth = (ii <= io) & (ii <= oi + 1e-9) & (oi < io)  # enters the outer box inside the cavity: hits its far side
    t_cup = np.where(hit_out, np.where(in_mouth, np.where(io < oo, io, np.inf), oi), np.inf)
    ci, co = _box(o, d_W, *OCC)
    t_occ = np.where(ci <= co, ci, np.inf)
    t_tab = np.where(d_W[:, 2] < 0, -c[2] / np.where(d_W[:, 2] < 0, d_W[:, 2], -1), np.inf)
    t = np.minimum(np.minimum(t_cup, t_occ), t_tab)
    seen = np.isfinite(t_cup) & (t_cup <= np.minimum(t_occ, t_tab))
    rays = RaySet(o[seen], d_W[seen], t[seen], np.full(seen.sum(), np.inf), np.ones(seen.sum()))
    fs = FreeSpace(K, X_WC, margin=0.005, px=1)
    fs.add(0, t.reshape(H, W).astype(np.float32), np.eye(4))
    return rays, fs


def test_open_columns_stop_at_the_first_of_surface_and_seen_empty():
    shape = (1, 1, 6)
    P = np.stack([np.zeros(6), np.zeros(6), np.arange(6.0)], 1)
    carved = np.array([0, 0, 0, 1, 1, 0], bool)
    surface = np.array([0, 0, 1, 0, 0, 0], bool)
    up = np.array([0.0, 0.0, 1.0])
    got = open_columns(np.array([0, 1, 2, 3]), P, np.zeros(3), 1.0, shape, carved, surface, up)
    assert got.tolist() == [False, False, True, True]  # 0, 1 meet the surface at 2 first; 2, 3 the carved voxels
    down = open_columns(np.array([5]), P, np.zeros(3), 1.0, shape, carved, surface, -up)
    assert down.tolist() == [True]


def test_closure_leaves_the_unseen_cavity_and_keeps_the_wall():
    rays, fs = _scene()
    P = rays.surface_points_O
    far = (np.abs(P[:, 0]) < 0.023) & (np.abs(P[:, 1] + 0.024) < 1e-4)
    assert far.any() and P[far, 2].min() < 0.04  # the far inner wall is seen through the mouth
    near = P[:, 1] > 0.0295
    assert near.any() and P[near, 2].min() > 0.025  # the occluder hides the lower part of the near wall
    cfg = SdfConfig(resolution=48, pad=0.01)
    hs = below_table_halfspace(np.eye(4), 0.0)
    hidden = np.array([[0.0, 0.016, 0.02], [0.01, 0.016, 0.022], [-0.01, 0.014, 0.025]])  # cavity behind the near wall
    wall = np.array([[0.0, 0.027, 0.02], [0.015, 0.027, 0.012], [-0.027, 0.02, 0.02]])  # near and side wall, low
    assert not fs.seen_through(hidden).any()  # the near wall lies on their line of sight
    assert np.all(hull_sdf(P, hidden) > 0)  # outside the hull of the seen points
    closed = carved_init(rays, cfg, fs, 0.005, support_O=hs)
    assert np.all(sdf_query(closed, hidden) < 0), sdf_query(closed, hidden)  # the closure fills the cavity
    assert np.all(sdf_query(closed, wall) < 0), sdf_query(closed, wall)
    opened = carved_init(rays, cfg, fs, 0.005, support_O=hs, open_dilate=1)
    assert np.all(sdf_query(opened, hidden) > 0), sdf_query(opened, hidden)
    assert np.all(sdf_query(opened, wall) < 0), sdf_query(opened, wall)
    plain = carved_init(rays, cfg, fs, 0.005)
    assert not np.all(sdf_query(plain, wall) < 0)  # without the closure the low wall is not all inside


def test_open_dilate_must_be_a_count():
    import pytest

    from service.tracking import TrackingConfig

    with pytest.raises(ValueError, match="sdf_support_open_dilate"):
        TrackingConfig(sdf_support_open_dilate=-1)


def test_open_gate_drops_the_closure_of_an_object_seen_into():
    rays, fs = _scene()
    cfg = SdfConfig(resolution=48, pad=0.01)
    hs = below_table_halfspace(np.eye(4), 0.0)
    plain = carved_init(rays, cfg, fs, 0.005)
    gated = carved_init(rays, cfg, fs, 0.005, support_O=hs, open_dilate=1, open_gate=0.05)
    assert np.array_equal(gated.values, plain.values)
    kept = carved_init(rays, cfg, fs, 0.005, support_O=hs, open_dilate=1, open_gate=1.0)
    assert not np.array_equal(kept.values, plain.values)
