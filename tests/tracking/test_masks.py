"""Masks trimmed by colour (service.tracking.masks): a mask shifted off the object loses the background strip it
covers, keeps the object, never grows; degenerate masks are kept; a session's masks are trimmed only when the trim takes
enough of them, and only for the visible geometry."""

import shutil
from dataclasses import replace

import cv2
import numpy as np
import pytest

from service.session import load_session
from service.tracking import TrackingConfig, TrackingInputs, run
from service.tracking.masks import TrimmedMasks, trim_mask


def _scene(shift: int = 6):
    """A black-and-white checker square on a blue table (RGB), its true mask and the mask shifted right by
    ``shift`` px (it covers a strip of table and misses a strip of the object)."""
    rng = np.random.default_rng(0)
    h, w = 120, 160
    rgb = np.zeros((h, w, 3), np.uint8)
    rgb[:] = (70, 120, 200)
    rgb = np.clip(rgb + rng.normal(0, 6, rgb.shape), 0, 255).astype(np.uint8)
    true = np.zeros((h, w), bool)
    true[30:90, 50:110] = True
    yy, xx = np.nonzero(true)
    checker = ((yy // 8 + xx // 8) % 2).astype(bool)
    rgb[yy, xx] = np.where(checker[:, None], (235, 235, 230), (25, 25, 30))
    given = np.roll(true, shift, axis=1)
    return rgb, true, given


def test_trim_removes_the_background_strip_and_keeps_the_object():
    rgb, true, given = _scene()
    out = trim_mask(rgb, given)
    strip = given & ~true
    assert strip.sum() == 6 * 60
    assert not (out & ~given).any()  # never adds a pixel
    assert (out & strip).sum() <= 0.2 * strip.sum()  # the table strip goes
    assert (out & true).sum() >= 0.97 * (given & true).sum()  # the object stays


def test_degenerate_masks_are_kept():
    rgb, true, _ = _scene()
    empty = np.zeros_like(true)
    assert not trim_mask(rgb, empty).any()
    thin = np.zeros_like(true)
    thin[60, 50:110] = True  # no core left after the erosion: no object seeds
    np.testing.assert_array_equal(trim_mask(rgb, thin), thin)
    np.testing.assert_array_equal(trim_mask(rgb, true, band_px=0), true)
    uniform = np.full_like(rgb, 128)  # colour cannot tell object from table: the cut would take most of it
    out = trim_mask(uniform, true)
    assert out.sum() >= 0.5 * true.sum() and not (out & ~true).any()


def test_trimmed_masks_view():
    rgb, true, given = _scene()

    class S:
        name = "s"
        calls = 0

        def rgb(self, i):
            return rgb

        def mask(self, i):
            S.calls += 1
            return given

    v = TrimmedMasks(S(), 6, 3)
    a, b = v.mask(0), v.mask(0)
    assert a is b and S.calls == 1  # computed once per frame
    assert v.name == "s"
    assert a.sum() < given.sum()


@pytest.mark.parametrize("field,value", [("mask_trim_px", 0), ("mask_trim_iters", 0), ("mask_trim_deep_px", 0), ("mask_trim_min", 1.5)])
def test_config_refuses_bad_values(field, value):
    with pytest.raises(ValueError, match=field):
        TrackingConfig(**{field: value})


def test_run_trims_only_misregistered_masks_and_only_for_the_visible_geometry(tiny_push_session, tmp_path):
    """The lab's exact masks are kept (the trim takes little of them); masks shifted 3 px sideways (at 240 x 180;
    about 7 px on the real video at 640 x 480) lose more, and when trimmed, the poses stay those of the given masks
    (tracking reads them) while the visible geometry is built from the trimmed ones."""
    s = tiny_push_session(24)
    cfg = replace(TrackingConfig.fast(), mask_trim_px=3, mask_trim_deep_px=2)
    exact = run(TrackingInputs(s), cfg)
    assert not exact.masks_trimmed and exact.mask_strip_fraction < cfg.mask_trim_min
    d = tmp_path / "s"
    shutil.copytree(s.root, d)
    for f in sorted((d / "masks").glob("*.png")):
        m = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(f), np.roll(m, 3, axis=1))
    shifted = load_session(d, "test")
    off = run(TrackingInputs(shifted), replace(cfg, mask_trim=False))
    assert off.mask_strip_fraction is None and not off.masks_trimmed
    on = run(TrackingInputs(shifted), replace(cfg, mask_trim_min=0.0))
    assert on.masks_trimmed and on.mask_strip_fraction > 2 * exact.mask_strip_fraction
    np.testing.assert_array_equal(on.X_WO, off.X_WO)
    assert on.visible_mesh.vertices.shape != off.visible_mesh.vertices.shape or not np.allclose(
        on.visible_mesh.vertices, off.visible_mesh.vertices)
