"""Keypoint depth from the surface around it (``spin.local_depth``, ``TrackingConfig.spin_depth_fit_px``): the depth
of a spin keypoint from a quadratic fitted to the mask's depth readings around it instead of its one pixel's
reading. On a noisy ray-cast cylinder the lifted keypoints must lie closer to the surface and the spin votes between
two frames must be tighter and still centred on the true spin; a quadratic surface is recovered exactly, stray
readings are dropped, a window with too few readings keeps the pixel's own reading."""

from __future__ import annotations

import numpy as np
import pytest

from service.tracking.spin import interior_features, local_depth, spin_votes, vote_mode
from service.tracking.tracker import _match
from service.tracking.types import TrackingConfig

from .test_spin import K, R_CYL, _camera, _render, _texture


def _quadric(h: int = 60, w: int = 80) -> np.ndarray:
    v, u = np.mgrid[0:h, 0:w].astype(float)
    return 0.8 + 1e-4 * (u - 30) + 2e-4 * (v - 20) + 3e-6 * (u - 40) ** 2 - 2e-6 * (u - 40) * (v - 30)


def test_quadratic_surface_exact_and_stray_readings_dropped():
    z = _quadric()
    mask = np.ones_like(z, bool)
    uv = np.array([[30.3, 20.7], [50.5, 41.2], [10.0, 10.0]])
    truth = 0.8 + 1e-4 * (uv[:, 0] - 30) + 2e-4 * (uv[:, 1] - 20) + 3e-6 * (uv[:, 0] - 40) ** 2 \
        - 2e-6 * (uv[:, 0] - 40) * (uv[:, 1] - 30)
    assert np.allclose(local_depth(z, mask, uv, 5, np.zeros(3)), truth, atol=1e-7)
    zs = z.copy()
    zs[18:21, 28:31] += 0.05  # nine flying pixels next to the first point
    got = local_depth(zs, mask, uv[:1], 5, np.zeros(1))
    assert abs(got[0] - truth[0]) < 2e-4


def test_too_few_readings_keep_the_pixel():
    z = _quadric()
    mask = np.zeros_like(z, bool)
    mask[20:23, 30:33] = True  # 9 readings < min_px
    out = local_depth(z, mask, np.array([[31.0, 21.0]]), 5, np.array([0.123]))
    assert out[0] == 0.123


def _radial_error(P_W: np.ndarray) -> np.ndarray:
    """Distance (m) of points in W from the cylinder's surface (axis x_W at height R_CYL)."""
    return np.abs(np.hypot(P_W[:, 1], P_W[:, 2] - R_CYL) - R_CYL)


def test_noisy_cylinder_keypoints_closer_and_votes_tighter():
    rng = np.random.default_rng(7)
    tex = _texture(np.random.default_rng(3), True)
    X_WC = _camera()
    spin = np.radians(4.0)
    frames = [_render(s, tex, X_WC) for s in (0.0, spin)]
    noisy = []
    for g, d, m in frames:
        dn = np.where(m, d + rng.normal(0.0, 0.002, d.shape), 0.0).astype(np.float32)  # 2 mm per pixel
        noisy.append((g, dn, m))
    raw = [interior_features(g, d, m, K, X_WC, 4, 300) for g, d, m in noisy]
    fit = [interior_features(g, d, m, K, X_WC, 4, 300, fit_px=5) for g, d, m in noisy]
    for (pr, dr), (pf, df) in zip(raw, fit):
        assert len(pr) == len(pf) > 30 and np.array_equal(dr, df)  # the same keypoints, only their depth differs
        cam = X_WC[:3, 3]
        ur = (pr - cam) / np.linalg.norm(pr - cam, axis=1, keepdims=True)
        uf = (pf - cam) / np.linalg.norm(pf - cam, axis=1, keepdims=True)
        assert np.max(np.linalg.norm(ur - uf, axis=1)) < 1e-9  # each on its own pixel's ray
        e_raw, e_fit = np.sqrt(np.mean(_radial_error(pr) ** 2)), np.sqrt(np.mean(_radial_error(pf) ** 2))
        assert e_fit < 0.4 * e_raw, (e_raw, e_fit)
    a, c = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, R_CYL])
    I = np.eye(4)
    spread = []
    for (p1, d1), (p0, d0) in ((raw[1], raw[0]), (fit[1], fit[0])):
        m = _match(d1, d0)
        th = spin_votes(p1[m[:, 0]], p0[m[:, 1]], I, I, a, c, 0.006)
        t, n = vote_mode(th, np.radians(3.0))
        # the cylinder turns by +spin about x_W: the vote of a surface point is its azimuth change, +spin
        assert abs(np.degrees(t) - 4.0) < 1.0
        spread.append(np.degrees(np.median(np.abs(th - np.median(th)))))
    assert spread[1] < 0.6 * spread[0], spread


def test_setting_validated():
    assert TrackingConfig().spin_depth_fit_px >= 0
    with pytest.raises(ValueError):
        TrackingConfig(spin_depth_fit_px=-1)
    with pytest.raises(ValueError):
        TrackingConfig(spin_depth_fit_px=2.5)
