"""The tracking loop's tight RANSAC over ORB matches (``track_ransac_thr``, ``tracker._feature_motion``)."""

import numpy as np
import pytest

from service.tracking.geometry import ransac_rigid
from service.tracking.tracker import _feature_motion
from service.tracking.types import TrackingConfig
from service.transforms import X_inv, rotation_angle, so3_exp


def _turning_cap(seed: int, deg: float = 10.0, static_frac: float = 0.2, noise: float = 0.0005):
    """Correspondences (point now in W, same point in O) of 80 keypoints on the camera-facing cap of a 3 cm sphere
    that turned ``deg`` about its centre (O = W at the previous frame): every surface keypoint moved 4–5 mm; a
    fraction ``static_frac`` are outline keypoints that stayed where they were (they follow the silhouette)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(80, 3))
    d[:, :2] *= 0.5
    d[:, 2] = np.abs(d[:, 2]) + 1.0
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    c = np.array([0.5, 0.0, 0.03])
    P_O = c + 0.03 * d
    R = so3_exp(np.radians(deg) * np.array([1.0, 0.0, 0.0]))
    P_W = (P_O - c) @ R.T + c
    static = rng.random(80) < static_frac
    P_W[static] = P_O[static]
    return P_W + rng.normal(scale=noise, size=P_W.shape), P_O, static


def _turn(fW, fO, cfg):
    Xr, inl = _feature_motion(fW, fO, cfg, np.random.default_rng(0))
    return float(np.degrees(rotation_angle(X_inv(Xr)[:3, :3]))), inl


def test_tight_threshold_drops_static_outline_keypoints():
    wide, tight, kept_wide, kept_tight = [], [], [], []
    for seed in range(10):
        fW, fO, static = _turning_cap(seed)
        a, inl = _turn(fW, fO, TrackingConfig())
        b, inl_t = _turn(fW, fO, TrackingConfig(track_ransac_thr=0.004))
        wide.append(10.0 - a)
        tight.append(10.0 - b)
        kept_wide.append(inl[static].mean())
        kept_tight.append(inl_t[static].mean())
    # 1 cm: every static keypoint is an inlier and the fit lags by about 1.7°; 4 mm: most are dropped
    assert np.median(kept_wide) == 1.0 and np.median(wide) > 1.2
    assert np.median(kept_tight) < 0.3 and np.median(tight) < 0.6
    assert np.median(tight) < 0.5 * np.median(wide)


def test_off_is_the_wide_ransac_and_fallback_when_too_few_inliers():
    fW, fO, _ = _turning_cap(0)
    cfg = TrackingConfig()
    X0, inl0 = _feature_motion(fW, fO, cfg, np.random.default_rng(0))
    X1, inl1 = ransac_rigid(fW, fO, cfg.ransac_thr, rng=np.random.default_rng(0), min_inliers=cfg.feat_min_inliers)
    assert np.array_equal(X0, X1) and np.array_equal(inl0, inl1)
    # keypoints as noisy as the threshold: the tight consensus has too few inliers, the wide one is used
    fW, fO, _ = _turning_cap(1, noise=0.004)
    tight = TrackingConfig(track_ransac_thr=0.0005)
    assert ransac_rigid(fW, fO, 0.0005, rng=np.random.default_rng(0), min_inliers=tight.feat_min_inliers)[0] is None
    X2, inl2 = _feature_motion(fW, fO, tight, np.random.default_rng(0))
    assert X2 is not None and inl2.sum() >= tight.feat_min_inliers


def test_config_rejects_a_negative_threshold():
    with pytest.raises(ValueError):
        TrackingConfig(track_ransac_thr=-0.001)
