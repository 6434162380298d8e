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


def _gated(fW, fO, cfg):
    return _feature_motion(fW, fO, cfg, np.random.default_rng(0), np.eye(4), np.random.default_rng(1))


def test_gate_keeps_the_tight_fit_where_it_separates_a_static_cluster():
    gate = TrackingConfig(track_ransac_thr=0.004, track_ransac_gate=True)
    lag_wide, lag_gate, kept = [], [], []
    for seed in range(10):
        fW, fO, static = _turning_cap(seed)
        a, _ = _turn(fW, fO, TrackingConfig())
        Xg, inl = _gated(fW, fO, gate)
        lag_wide.append(10.0 - a)
        lag_gate.append(10.0 - float(np.degrees(rotation_angle(X_inv(Xg)[:3, :3]))))
        kept.append(inl[static].mean())
    assert np.median(kept) < 0.3  # the tight consensus was taken: most outline keypoints left out
    assert np.median(lag_gate) < 0.6 and np.median(lag_gate) < 0.5 * np.median(lag_wide)


@pytest.mark.parametrize("deg,static_frac", [(2.0, 0.2), (10.0, 0.0)])
def test_gate_keeps_the_wide_fit_bit_for_bit_without_two_motions(deg, static_frac):
    # 2°: the surface moves under 1 mm, every match fits the previous pose as well; 10° without static keypoints:
    # nothing fits the previous pose. Either way the 1 cm fit from the main random stream, as without the option.
    gate = TrackingConfig(track_ransac_thr=0.004, track_ransac_gate=True)
    for seed in range(5):
        fW, fO, _ = _turning_cap(seed, deg=deg, static_frac=static_frac)
        Xg, ig = _gated(fW, fO, gate)
        Xw, iw = ransac_rigid(fW, fO, gate.ransac_thr, rng=np.random.default_rng(0), min_inliers=gate.feat_min_inliers)
        assert np.array_equal(Xg, Xw) and np.array_equal(ig, iw)


def test_gate_needs_the_previous_pose_and_a_positive_count():
    fW, fO, _ = _turning_cap(0)
    gate = TrackingConfig(track_ransac_thr=0.004, track_ransac_gate=True)
    # without X_prev the plain option runs (tight first), as the function did before the gate
    X0, _ = _feature_motion(fW, fO, gate, np.random.default_rng(0))
    X1, _ = _feature_motion(fW, fO, TrackingConfig(track_ransac_thr=0.004), np.random.default_rng(0))
    assert np.array_equal(X0, X1)
    with pytest.raises(ValueError):
        TrackingConfig(track_gate_min=0)


def test_gate_ignores_a_body_at_rest_with_keypoint_noise_near_the_threshold():
    # at rest with keypoints as noisy as the tight threshold, some 1 cm inliers that fit the previous pose fall out of
    # the tight fit by noise alone; the tight fit does not move its inliers by the threshold, so nothing is separated
    from service.tracking.tracker import _separates

    gate = TrackingConfig(track_ransac_thr=0.004, track_ransac_gate=True)
    noisy_outliers = 0
    for seed in range(10):
        fW, fO, _ = _turning_cap(seed, deg=0.0, static_frac=0.0, noise=0.002)
        Xl, il = ransac_rigid(fW, fO, gate.ransac_thr, rng=np.random.default_rng(0), min_inliers=12)
        Xt, it = ransac_rigid(fW, fO, 0.004, rng=np.random.default_rng(1), min_inliers=12)
        still = np.linalg.norm(fW - fO, axis=1) < 0.004
        noisy_outliers += int(np.sum(il & still & ~it) >= gate.track_gate_min)
        assert _separates(fW, fO, il, it, np.eye(4), 0.004, Xt) == 0
        Xg, ig = _gated(fW, fO, gate)
        assert np.array_equal(Xg, Xl) and np.array_equal(ig, il)
    assert noisy_outliers > 0
