"""Readings other views saw through (``service.sdf.contradicted_readings``) and the tracking options of the views'
evidence."""

import numpy as np
import pytest

from service.sdf import RaySet

from .plate import plate_views as _views


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

    for name, bad in (("sdf_band_px", -1), ("sdf_contradict_margin", -0.001), ("sdf_contradict_views", 0)):
        with pytest.raises(ValueError, match=name):
            TrackingConfig(**{name: bad})
