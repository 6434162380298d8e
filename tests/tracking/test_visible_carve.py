"""Carved initialisation of the visible SDF (``visible.carved_init``): an open box seen from above. The convex hull
of its observed points (rim and floor) fills the cavity; the voxels a keyframe saw through are set outside, the
walls and the floor stay inside."""

import numpy as np

from service.sdf import RaySet, SdfConfig, sdf_query
from service.sdf.fit import hull_sdf
from service.tracking.tracker import FreeSpace
from service.tracking.visible import carved_init
from service.transforms import make_X

H_CAM = 0.4  # camera height above the table (O = W), looking straight down


def _scene():
    g = np.linspace(-0.03, 0.03, 25)
    X, Y = np.meshgrid(g, g)
    rim = (np.maximum(np.abs(X), np.abs(Y)) > 0.024).ravel()
    P = np.concatenate([np.c_[X.ravel()[rim], Y.ravel()[rim], np.full(rim.sum(), 0.05)],  # rim, walls 6 mm
                        np.c_[X.ravel()[~rim], Y.ravel()[~rim], np.full((~rim).sum(), 0.01)],  # floor
                        [[sx * 0.03, sy * 0.03, z] for sx in (-1, 1) for sy in (-1, 1) for z in (0.0, 0.05)]])  # sides
    o = np.array([0.0, 0.0, H_CAM])
    depth = H_CAM - P[:, 2]  # camera z = −z_W
    dirs = (P - o) / depth[:, None]
    rays = RaySet(np.tile(o, (len(P), 1)), dirs, depth, np.full(len(P), np.inf), np.ones(len(P)))
    # the keyframe's depth image: floor inside the cavity, rim on the walls, table elsewhere
    K = np.array([[400.0, 0, 80], [0, 400.0, 80], [0, 0, 1]])
    u, v = np.meshgrid(np.arange(160), np.arange(160))
    img = np.full((160, 160), H_CAM, np.float32)
    for zs, half in ((0.05, 0.03), (0.01, 0.024)):  # the wall top, then the floor seen through the opening
        d = H_CAM - zs
        x, y = (u - 80) / 400 * d, -(v - 80) / 400 * d
        img[(np.abs(x) <= half) & (np.abs(y) <= half)] = d
    X_WC = make_X(np.diag([1.0, -1.0, -1.0]), o)  # x right, y down in the image = −y_W, z = −z_W
    fs = FreeSpace(K, X_WC, margin=0.01, px=1)
    fs.add(0, img, np.eye(4))
    return rays, fs


def test_carved_init_opens_the_cavity_and_keeps_the_walls():
    rays, fs = _scene()
    cfg = SdfConfig(resolution=40, pad=0.01)
    g = carved_init(rays, cfg, fs, 0.005)
    cavity = np.array([[0.0, 0.0, 0.03], [0.01, -0.01, 0.04], [0.0, 0.01, 0.025]])  # ≥ carve margin above the floor
    walls = np.array([[0.027, 0.0, 0.03], [0.0, -0.027, 0.02], [0.0, 0.0, 0.005]])  # wall interiors, under the floor
    assert np.all(hull_sdf(rays.surface_points_O, cavity) < -0.005)  # the hull alone fills the cavity
    assert np.all(sdf_query(g, cavity) >= 0.0049), sdf_query(g, cavity)
    assert np.all(sdf_query(g, walls) < 0), sdf_query(g, walls)


def test_carve_value_must_be_outside():
    import pytest

    from service.tracking import TrackingConfig

    with pytest.raises(ValueError, match="sdf_carve_value"):
        TrackingConfig(sdf_carve_value=0.0)
