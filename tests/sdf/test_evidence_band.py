"""The thickness behind each reading measured by other views (``service.sdf.evidence_band``): a plate thinner than τ
seen from both sides gets its thickness and comes out thin in the fit (``fit_sdf(band_back=...)``); a slab thicker
than τ, or one seen from one side only, gets none (∞: BundleSDF's full band)."""

import numpy as np
import pytest

from service.sdf import RaySet, SdfConfig, evidence_band, fit_sdf

from .plate import fit_thickness
from .plate import plate_views as _views


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
    t_ev = fit_thickness(rays, band_back=band)
    t_sym = fit_thickness(rays)
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
