"""The leave-one-out keyframe refinement's starting correspondence radius (``refine_dist0``, ``tracker._refine_keyframes``).

The radius is the largest pose error the refinement can still correct, and the distance up to which a keyframe's
points on surface no other keyframe saw are matched to other surface (docs/tracking-findings.md, "Worst frames of
pivots just over 5°"). Checked here: the setting reaches every registration of the round, its default is the former
fixed 15 mm, a keyframe 9 mm off is pulled back with 15 mm and left with the 6 mm radius, and bad values are refused.
"""

from dataclasses import replace

import numpy as np
import pytest

from service.tracking import TrackingConfig
from service.tracking import tracker
from service.tracking.tracker import Keyframe, _refine_keyframes


def _box_points(h: float = 0.004) -> tuple[np.ndarray, np.ndarray]:
    """Three faces of a 6 × 6 × 12 cm box meeting at a corner (x = 0.03, y = −0.03 front, z = 0.06 top), in O,
    with their outward normals: every direction of motion is fixed by them."""
    a = np.arange(-0.03, 0.03 + 1e-9, h)
    b = np.arange(-0.06, 0.06 + 1e-9, h)
    A, B = np.meshgrid(a, b)
    side = np.c_[np.full(A.size, 0.03), A.ravel(), B.ravel()]
    front = np.c_[A.ravel(), np.full(A.size, -0.03), B.ravel()]
    A2, C2 = np.meshgrid(a, a)
    top = np.c_[A2.ravel(), C2.ravel(), np.full(A2.size, 0.06)]
    P = np.r_[side, front, top]
    N = np.r_[np.tile([1.0, 0, 0], (len(side), 1)), np.tile([0, -1.0, 0], (len(front), 1)),
              np.tile([0, 0, 1.0], (len(top), 1))]
    return P, N


def _keyframes(offset: np.ndarray) -> list[Keyframe]:
    """Three keyframes of the same box at rest (true pose identity); the last one's pose is off by ``offset`` (m)."""
    P, N = _box_points()
    out = []
    for i, off in enumerate([np.zeros(3), np.zeros(3), offset]):
        X = np.eye(4)
        X[:3, 3] = off
        P_O = P - off  # its points placed in O with the wrong pose
        out.append(Keyframe(i, X, P_O, P.copy(), N.copy(), np.zeros((0, 3)), None, np.zeros((0, 3))))
    return out


def _icp_kw(cfg: TrackingConfig) -> dict:
    return dict(iters=cfg.icp_iters, dist0=cfg.icp_dist0, dist_min=cfg.icp_dist_min, inlier_dist=cfg.inlier_dist)


def test_default_is_the_former_fixed_radius():
    assert TrackingConfig().refine_dist0 == 0.015


@pytest.mark.parametrize("d0", [0.015, 0.006, 0.01])
def test_the_radius_reaches_every_registration_of_the_round(monkeypatch, d0):
    seen = []
    real = tracker.icp

    def spy(*a, **k):
        seen.append((k["dist0"], k["dist_min"]))
        return real(*a, **k)

    monkeypatch.setattr(tracker, "icp", spy)
    cfg = replace(TrackingConfig(), refine_dist0=d0)
    _refine_keyframes(_keyframes(np.zeros(3)), cfg, None, _icp_kw(cfg))
    assert seen == [(d0, cfg.icp_dist_min)] * 2


def test_the_radius_bounds_the_error_the_refinement_corrects():
    """A keyframe 9 mm off along each of the three faces' normals is brought back with the 15 mm radius; with 6 mm
    its points find no surface of the others within reach and it keeps its pose (the price of the smaller radius)."""
    off = 0.009 * np.array([1.0, -1.0, 1.0])
    for d0, expect_back in [(0.015, True), (0.006, False)]:
        cfg = replace(TrackingConfig(), refine_dist0=d0)
        kfs = _keyframes(off)
        _refine_keyframes(kfs, cfg, None, _icp_kw(cfg))
        err = np.linalg.norm(kfs[2].X_WO[:3, 3])
        if expect_back:
            assert err < 0.001, (d0, err)
        else:
            assert err > 0.015, (d0, err)
        assert np.allclose(kfs[1].X_WO, np.eye(4))  # the right one stays


@pytest.mark.parametrize("v", [0.005, 0.0, -0.01, float("nan"), float("inf"), True])
def test_bad_radius_is_refused(v):
    with pytest.raises(ValueError, match="refine_dist0"):
        replace(TrackingConfig(), refine_dist0=v)


def test_radius_at_the_final_radius_is_accepted():
    cfg = replace(TrackingConfig(), refine_dist0=TrackingConfig().icp_dist_min)
    assert cfg.refine_dist0 == 0.006
