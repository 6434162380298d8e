"""The thickness behind each reading measured by other views (``service.sdf.evidence_band``): a plate thinner than τ
seen from both sides gets its thickness and comes out thin in the fit (``fit_sdf(band_back=...)``); a slab thicker
than τ, or one seen from one side only, gets none (∞: BundleSDF's full band)."""

import numpy as np
import pytest

from service.sdf import RaySet, SdfConfig, evidence_band, fit_sdf, rays_from_frame, sdf_query
from service.transforms import X_inv, make_X

H, W = 40, 40
K = np.array([[300.0, 0, W / 2], [0, 300.0, H / 2], [0, 0, 1]])


def _views(t, sides=(0, 1)):
    """Rays and views (K, X_CO, depth) of a slab x in [0, t], |y|, |z| <= 3 cm, seen along ±x."""
    parts, views = [], []
    for k, (cx, sgn) in enumerate(((-0.25, 1.0), (0.25 + t, -1.0))):
        if k not in sides:
            continue
        z = np.array([sgn, 0.0, 0.0])
        x = np.array([0.0, sgn, 0.0])
        X_OC = make_X(np.stack([x, np.cross(z, x), z], 1), np.array([cx, 0.0, 0.0]))
        u, v = np.meshgrid(np.arange(W), np.arange(H))
        d = np.stack([u, v, np.ones_like(u)], -1, dtype=float) @ np.linalg.inv(K).T @ X_OC[:3, :3].T  # camera-z = 1
        face = 0.0 if sgn > 0 else t
        zc = (face - cx) / d[..., 0]  # camera depth where the ray meets the face
        hit = zc[..., None] * d + np.array([cx, 0.0, 0.0])
        mask = (np.abs(hit[..., 1]) < 0.03) & (np.abs(hit[..., 2]) < 0.03)
        depth = np.where(mask, zc, 0.5).astype(np.float32)  # background wall 0.5 m away
        parts.append(rays_from_frame(depth, mask, K, X_OC, stride=1, ring_px=4, rng=np.random.default_rng(k)))
        views.append((K, X_inv(X_OC), depth))
    return RaySet.concatenate(parts), views


def _inner(rays, band):
    """Object rays whose surface point the other view also sees (|y|, |z| < 1.2 cm)."""
    P = rays.surface_points_O
    m = rays.depth > 0
    inner = np.zeros(len(rays), bool)
    inner[np.nonzero(m)[0]] = (np.abs(P[:, 1]) < 0.012) & (np.abs(P[:, 2]) < 0.012)
    return band[inner]


def test_band_stops_at_the_far_side_of_a_thin_plate():
    rays, views = _views(0.004)
    band = evidence_band(rays, views, 0.01, margin=0.002, step=0.001, px=1)
    b = _inner(rays, band)
    assert np.all(np.abs(b - 0.004) <= 0.0006), (b.min(), b.max())
    assert np.all(np.isinf(band[rays.depth == 0]))


def test_band_keeps_trunc_behind_a_thick_slab_or_one_view():
    rays, views = _views(0.03)
    assert np.all(np.isinf(_inner(rays, evidence_band(rays, views, 0.01, px=1))))
    rays, views = _views(0.004, sides=(0,))
    assert np.all(np.isinf(_inner(rays, evidence_band(rays, views, 0.01, px=1))))


def test_evidence_band_keeps_a_thin_plate_thin():
    rays, views = _views(0.004)
    band = evidence_band(rays, views, 0.01, margin=0.002, px=1)
    cfg = SdfConfig(resolution=40, steps=150, rays_per_step=512, samples_near=12, samples_far=6)
    xs = np.linspace(-0.02, 0.024, 441)
    yz = np.random.default_rng(0).uniform(-0.015, 0.015, (20, 2))

    def thickness(g):
        th = [(sdf_query(g, np.stack([xs, np.full_like(xs, y), np.full_like(xs, z)], 1)) < 0).sum() * (xs[1] - xs[0])
              for y, z in yz]
        return float(np.median(th))

    bounds = np.array([[-0.03, -0.04, -0.04], [0.034, 0.04, 0.04]])
    t_ev = thickness(fit_sdf(rays, cfg, bounds_O=bounds, band_back=band))
    t_sym = thickness(fit_sdf(rays, cfg, bounds_O=bounds))
    assert abs(t_ev - 0.004) < 0.0015, t_ev
    assert t_sym > t_ev + 0.002, (t_sym, t_ev)


def test_band_back_is_validated():
    rays, _ = _views(0.004, sides=(0,))
    with pytest.raises(ValueError, match="band_back"):
        fit_sdf(rays, SdfConfig.fast(), band_back=np.zeros(3))
    with pytest.raises(ValueError, match="band_back"):
        fit_sdf(rays, SdfConfig.fast(), band_back=np.full(len(rays), -0.001))


def test_contradicted_readings_finds_a_reading_other_views_saw_through():
    from service.sdf import contradicted_readings

    rays, views = _views(0.03)
    bad = contradicted_readings(rays, views, margin=0.003, px=1)
    assert not bad.any()  # a consistent slab: no reading is contradicted
    # a stray reading 2 cm in front of the face x = 0 (a flying pixel), which the view from +x sees through
    o, d = rays.origins_O[:1], rays.dirs_O[:1]
    zc = (-0.02 - o[0, 0]) / d[0, 0]
    stray = RaySet(o, d, np.array([zc]), np.array([np.inf]), np.ones(1))
    both = RaySet.concatenate([rays, stray])
    bad = contradicted_readings(both, views, margin=0.003, px=1)
    assert bad[-1] and not bad[:-1].any()


def test_tracking_options_are_validated():
    from service.tracking import TrackingConfig

    for name, bad in (("sdf_band_margin", -0.001), ("sdf_band_px", -1), ("sdf_band_frames", -1),
                      ("sdf_contradict_margin", -0.001), ("sdf_contradict_views", 0)):
        with pytest.raises(ValueError, match=name):
            TrackingConfig(**{name: bad})
