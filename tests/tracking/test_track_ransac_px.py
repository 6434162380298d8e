"""The tracking loop's consensus measured in the camera (``track_ransac_px``, ``geometry.ray_inliers``)."""

import numpy as np
import pytest

from service.tracking.geometry import ransac_rigid, ray_inliers
from service.tracking.tracker import _feature_motion
from service.tracking.types import TrackingConfig
from service.transforms import X_inv, make_X, rotation_angle, so3_exp

K = np.array([[615.0, 0.0, 320.0], [0.0, 615.0, 240.0], [0.0, 0.0, 1.0]])
X_CW = np.eye(4)  # the camera at the origin of W looking along +z


def _rolling_cap(seed: int, deg: float = 10.0, static_frac: float = 0.25, axial: float = 0.0025, px: float = 0.3):
    """Correspondences (point now in W, same point in O) of 80 keypoints on the camera-facing cap of a 3 cm sphere
    0.8 m in front of the camera that turned ``deg`` about its centre, about an axis across the view (O = W at the
    previous frame; the surface moved 4-5 mm, 3-4 px, mostly across the ray). A fraction ``static_frac`` are outline
    keypoints that stayed where they were. Every current keypoint has the sensor's noise: ``axial`` (m, 1 σ) along
    its camera ray (the depth reading), ``px`` pixels across it."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(80, 3))
    d[:, :2] *= 0.5
    d[:, 2] = -np.abs(d[:, 2]) - 1.0  # the half facing the camera (−z)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    c = np.array([0.0, 0.0, 0.8])
    P_O = c + 0.03 * d
    R = so3_exp(np.radians(deg) * np.array([1.0, 0.0, 0.0]))
    P_W = (P_O - c) @ R.T + c
    static = rng.random(80) < static_frac
    P_W[static] = P_O[static]
    ray = P_W / np.linalg.norm(P_W, axis=1, keepdims=True)
    z = P_W[:, 2:]
    across = rng.normal(scale=px / K[0, 0], size=(80, 2)) * z
    P_W = P_W + ray * rng.normal(scale=axial, size=(80, 1))
    P_W[:, :2] += across
    return P_W, P_O, static


def _lag(Xr):
    return 10.0 - float(np.degrees(rotation_angle(X_inv(Xr)[:3, :3])))


def test_camera_consensus_drops_static_keypoints_and_keeps_noisy_depth():
    lag_wide, lag_ray, kept = [], [], {"wide": [], "tight": [], "ray": []}
    for seed in range(10):
        fW, fO, static = _rolling_cap(seed)
        Xw, iw = _feature_motion(fW, fO, TrackingConfig(), np.random.default_rng(0), cam=(K, X_CW))
        Xt, it = ransac_rigid(fW, fO, 0.004, rng=np.random.default_rng(0), min_inliers=12)  # a 4 mm ball
        Xr, ir = _feature_motion(fW, fO, TrackingConfig(track_ransac_px=2.0), np.random.default_rng(0), cam=(K, X_CW))
        lag_wide.append(_lag(Xw))
        lag_ray.append(_lag(Xr))
        for k, inl in (("wide", iw), ("tight", it), ("ray", ir)):
            kept[k].append((inl[static].mean(), inl[~static].mean()))
    wide, tight, ray = (np.median(np.array(kept[k]), 0) for k in ("wide", "tight", "ray"))
    # 1 cm: every static keypoint is an inlier and the fit lags by about 1.9°; 4 mm: drops most static ones and an
    # eighth of the surface's (their depth noise); in the camera: the static ones go, the surface's stay, no lag
    assert wide[0] == 1.0 and np.median(lag_wide) > 1.5
    assert tight[1] < 0.9
    assert ray[0] < 0.1 and ray[1] > 0.95
    assert abs(np.median(lag_ray)) < 0.5


def test_ray_inliers_matches_a_direct_projection():
    fW, fO, _ = _rolling_cap(3)
    R = so3_exp(np.radians(9.0) * np.array([1.0, 0.0, 0.0]))  # near the true turn: some inliers, not all
    c = np.array([0.0, 0.0, 0.8])
    X = make_X(R.T, c - R.T @ c)  # b ≈ X a
    X_CA = make_X(so3_exp(np.array([0.01, 0.02, -0.01])), np.array([0.001, 0.002, 0.005]))
    got = ray_inliers(fW, fO, X[None], (K, X_CA, 2.0), 0.004)[0]
    pred = fO @ X_inv(X)[:3, :3].T + X_inv(X)[:3, 3]
    a = fW @ X_CA[:3, :3].T + X_CA[:3, 3]
    p = pred @ X_CA[:3, :3].T + X_CA[:3, 3]
    uv = lambda q: (q[:, :2] / q[:, 2:]) * K[0, 0]
    want = (np.linalg.norm(uv(a) - uv(p), axis=1) < 2.0) & (np.abs(a[:, 2] - p[:, 2]) < 0.004)
    assert np.array_equal(got, want) and 0 < want.sum() < len(want)


def test_off_is_the_previous_ransac_and_fallback_when_too_few_inliers():
    fW, fO, _ = _rolling_cap(0)
    cfg = TrackingConfig()
    X0, inl0 = _feature_motion(fW, fO, cfg, np.random.default_rng(0), cam=(K, X_CW))
    X1, inl1 = ransac_rigid(fW, fO, cfg.ransac_thr, rng=np.random.default_rng(0), min_inliers=cfg.feat_min_inliers)
    assert np.array_equal(X0, X1) and np.array_equal(inl0, inl1)
    # keypoints far noisier across the ray than the threshold: too few inliers in the camera, the 1 cm ball is used
    fW, fO, _ = _rolling_cap(1, px=8.0)
    on = TrackingConfig(track_ransac_px=0.5)
    assert ransac_rigid(fW, fO, on.ransac_thr, rng=np.random.default_rng(0), min_inliers=on.feat_min_inliers,
                        cam=(K, X_CW, 0.5))[0] is None
    X2, inl2 = _feature_motion(fW, fO, on, np.random.default_rng(0), cam=(K, X_CW))
    assert X2 is not None and inl2.sum() >= on.feat_min_inliers


@pytest.mark.parametrize("bad", [0.0, -1.0, True, "2"])
def test_config_rejects_bad_pixel_thresholds(bad):
    with pytest.raises(ValueError):
        TrackingConfig(track_ransac_px=bad)
