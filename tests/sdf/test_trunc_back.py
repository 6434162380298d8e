"""The band behind the observed surface (``SdfConfig.trunc_back``): a plate thinner than the truncation τ,
seen from both sides. With BundleSDF's symmetric band every reading also claims the τ behind it as inside, which
reaches through the plate into the air on the other side and thickens it; a shallow band keeps its thickness."""

import pytest

from service.sdf import SdfConfig

from .plate import fit_thickness, plate_views

T = 0.004  # plate x in [0, T], |y|, |z| <= 3 cm


def _thickness(back):
    rays, _ = plate_views(T, background=0.0)
    return fit_thickness(rays, trunc_back=back)


def test_shallow_band_keeps_a_thin_plate_thin():
    thick_sym = _thickness(None)
    thick_back = _thickness(0.002)
    assert abs(thick_back - T) < 0.0015, thick_back
    assert thick_sym > thick_back + 0.002, (thick_sym, thick_back)


def test_trunc_back_is_validated():
    with pytest.raises(ValueError, match="trunc_back"):
        SdfConfig(trunc_back=0.02)
    with pytest.raises(ValueError, match="trunc_back"):
        SdfConfig(trunc_back=0.0)
