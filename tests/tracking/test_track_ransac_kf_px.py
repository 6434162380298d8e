"""The camera consensus' band for keyframe matches (``track_ransac_kf_px``, ``tracker._feature_corr`` with
``sources``, ``tracker._feature_motion`` with ``from_kf``, ``geometry.ray_inliers`` with one band per match)."""

from types import SimpleNamespace

import numpy as np
import pytest

from service.tracking.geometry import ray_inliers
from service.tracking.tracker import _feature_corr, _feature_motion
from service.tracking.types import TrackingConfig
from service.transforms import X_inv, make_X

K = np.array([[615.0, 0.0, 320.0], [0.0, 615.0, 240.0], [0.0, 0.0, 1.0]])
X_CW = np.eye(4)  # the camera at the origin of W looking along +z


def _drifted_push(seed: int, lag: float = 0.004, n_prev: int = 60, n_kf: int = 40):
    """Correspondences of a box face 0.8 m in front of the camera (O = W at the truth of this frame): ``n_prev``
    matches to the previous frame, whose tracked pose lags the truth by ``lag`` (m) across the view (x), so their
    points in O are shifted by it, and ``n_kf`` to a keyframe whose pose is right. Every current keypoint has the
    sensor's noise: 2.5 mm (1 σ) along its camera ray, 0.3 px across it. Returns fW, fO, from_kf."""
    rng = np.random.default_rng(seed)
    n = n_prev + n_kf
    P = np.c_[rng.uniform(-0.05, 0.05, (n, 2)), 0.8 + rng.uniform(-0.01, 0.01, n)]
    fO = P.copy()
    fO[:n_prev, 0] -= lag  # placed with the lagging previous pose
    ray = P / np.linalg.norm(P, axis=1, keepdims=True)
    fW = P + ray * rng.normal(scale=0.0025, size=(n, 1))
    fW[:, :2] += rng.normal(scale=0.3 / K[0, 0], size=(n, 2)) * P[:, 2:]
    return fW, fO, np.arange(n) >= n_prev


def test_keyframe_band_keeps_the_keyframe_matches_and_pulls_the_lag_back():
    err, kept = {2: [], 4: []}, {2: [], 4: []}
    for seed in range(10):
        fW, fO, from_kf = _drifted_push(seed)
        for kf_px in (2, 4):
            cfg = TrackingConfig(track_ransac_px=2.0, track_ransac_kf_px=float(kf_px))
            Xr, inl = _feature_motion(fW, fO, cfg, np.random.default_rng(0), cam=(K, X_CW), from_kf=from_kf)
            Xe, c = X_inv(Xr), np.array([0.0, 0.0, 0.8])  # the truth is the identity: the face's centre moved by
            err[kf_px].append(1e3 * np.linalg.norm(Xe[:3, :3] @ c + Xe[:3, 3] - c))
            kept[kf_px].append(inl[from_kf].mean())
    # 2 px for every match: the previous frame's group wins alone (its lag, 4 mm = 3.1 px, kept); 4 px for the
    # keyframe's: both groups enter and the fit moves toward the keyframe's right pose (60 % of the lag left)
    assert np.median(kept[2]) < 0.3 and np.median(kept[4]) > 0.9
    assert np.median(err[2]) > 3.5 and np.median(err[4]) < np.median(err[2]) - 1.0


def test_off_and_equal_bands_are_the_single_band_bit_for_bit():
    fW, fO, from_kf = _drifted_push(1)
    one = TrackingConfig(track_ransac_px=2.0)
    X0, i0 = _feature_motion(fW, fO, one, np.random.default_rng(0), cam=(K, X_CW))
    X1, i1 = _feature_motion(fW, fO, one, np.random.default_rng(0), cam=(K, X_CW), from_kf=from_kf)
    X2, i2 = _feature_motion(fW, fO, TrackingConfig(track_ransac_px=2.0, track_ransac_kf_px=2.0),
                             np.random.default_rng(0), cam=(K, X_CW), from_kf=from_kf)
    assert np.array_equal(X0, X1) and np.array_equal(i0, i1)
    assert np.array_equal(X0, X2) and np.array_equal(i0, i2)
    Xs = np.stack([np.eye(4), make_X(np.eye(3), np.array([-0.004, 0.0, 0.0]))])  # the truth, the lagging pose
    a = ray_inliers(fW, fO, Xs, (K, X_CW, 2.0), 0.01)
    b = ray_inliers(fW, fO, Xs, (K, X_CW, np.full(len(fW), 2.0)), 0.01)
    c = ray_inliers(fW, fO, Xs, (K, X_CW, np.where(from_kf, 4.0, 2.0)), 0.01)
    assert np.array_equal(a, b) and np.array_equal(c[:, ~from_kf], a[:, ~from_kf])
    assert (c[:, from_kf] >= a[:, from_kf]).all() and c.sum() > a.sum()


def test_feature_corr_marks_the_keyframe_matches():
    rng = np.random.default_rng(0)
    desc = rng.integers(0, 256, (30, 32), dtype=np.uint8)
    kp = rng.normal(size=(30, 3))
    o = SimpleNamespace(desc=desc, kp_W=kp)
    prev = SimpleNamespace(desc=desc[:20], kp_W=kp[:20])
    kf = SimpleNamespace(desc=desc[10:], kp_O=kp[10:])
    A, B = _feature_corr(o, prev, np.eye(4), [kf], lost=False)
    A2, B2, from_kf = _feature_corr(o, prev, np.eye(4), [kf], lost=False, sources=True)
    assert np.array_equal(A, A2) and np.array_equal(B, B2)
    assert from_kf.tolist() == [False] * 20 + [True] * 20
    none = SimpleNamespace(desc=None, kp_W=kp)
    assert [len(x) for x in _feature_corr(none, prev, np.eye(4), [kf], lost=False, sources=True)] == [0, 0, 0]


@pytest.mark.parametrize("bad", [0.0, -1.0, True, "4"])
def test_config_rejects_bad_keyframe_bands(bad):
    with pytest.raises(ValueError):
        TrackingConfig(track_ransac_kf_px=bad)
