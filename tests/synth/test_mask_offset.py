"""The lab's misregistered segmentation (SynthSpec.mask_offset_px): the mask moves sideways, the object's depth bleeds
into the strip of background it covers, nothing else changes; a bad offset is refused."""

import numpy as np
import pytest

from service.synth import SynthSpec, make_session
from service.synth.noise import misregister_mask


def test_misregister_mask_shifts_and_bleeds():
    mask = np.zeros((20, 30), bool)
    mask[5:15, 10:20] = True
    z = np.full((20, 30), 2.0)
    z[mask] = 1.0
    m2, z2 = misregister_mask(mask, z, 3)
    np.testing.assert_array_equal(m2, np.roll(mask, 3, axis=1))
    strip = m2 & ~mask
    assert strip.sum() == 30 and np.all(z2[strip] == 1.0)  # object depth bled into the strip
    np.testing.assert_array_equal(z2[~strip], z[~strip])
    m3, z3 = misregister_mask(mask, z, -2)
    np.testing.assert_array_equal(m3, np.roll(mask, -2, axis=1))
    assert np.all(z3[m3 & ~mask] == 1.0)
    m0, z0 = misregister_mask(mask, z, 0)
    assert m0 is mask and z0 is z


def test_bad_offset_refused(tmp_path):
    with pytest.raises(ValueError, match="mask_offset_px"):
        make_session(SynthSpec(preset="tiny", resolution=(64, 48), n_frames=2, mask_offset_px=40), tmp_path / "s")
