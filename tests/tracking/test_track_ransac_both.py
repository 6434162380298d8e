"""Both feature consensuses as candidate starts (``track_ransac_both``, ``tracker._ball_hypothesis``,
``tracker._register_candidates``, ``tracker._feature_motion`` with ``kind``)."""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial import cKDTree

from service.tracking.tracker import _ball_hypothesis, _feature_motion, _register_candidates
from service.tracking.types import TrackingConfig
from service.transforms import X_inv, make_X, pose_distance, so3_exp

from tests.tracking.test_track_ransac_px import K, X_CW, _rolling_cap

ICP_KW = dict(iters=15, dist0=0.03, dist_min=0.006, inlier_dist=0.008, normal_cos=0.0)


def test_feature_motion_names_the_consensus_it_used():
    fW, fO, _ = _rolling_cap(0)
    cfg = TrackingConfig(track_ransac_px=2.0)
    X2, i2 = _feature_motion(fW, fO, cfg, np.random.default_rng(0), cam=(K, X_CW))
    X3, i3, kind = _feature_motion(fW, fO, cfg, np.random.default_rng(0), cam=(K, X_CW), kind=True)
    assert kind == "camera" and np.array_equal(X2, X3) and np.array_equal(i2, i3)  # the same fit, bit for bit
    assert _feature_motion(fW, fO, TrackingConfig(), np.random.default_rng(0), kind=True)[2] == "ball"
    # too few inliers in the camera (a band far below the keypoints' noise): the ball takes over and says so
    tiny = TrackingConfig(track_ransac_px=0.01, feat_min_inliers=12)
    assert _feature_motion(fW, fO, tiny, np.random.default_rng(0), cam=(K, X_CW), kind=True)[2] == "ball"


def test_ball_hypothesis_keeps_the_static_keypoints_the_camera_drops():
    fW, fO, static = _rolling_cap(1)
    cfg = TrackingConfig(track_ransac_px=2.0)
    _, inl_cam = _feature_motion(fW, fO, cfg, np.random.default_rng(0), cam=(K, X_CW))
    start, bW, bO = _ball_hypothesis(fW, fO, inl_cam, cfg, np.random.default_rng(0))
    # the ball's inliers: every static outline keypoint too (the camera keeps almost none), so its start lags
    inl_ball = np.array([np.any(np.all(bW == p, axis=1)) for p in fW])
    assert inl_ball[static].all() and inl_cam[static].mean() < 0.1
    assert np.allclose(start[3], [0, 0, 0, 1]) and len(bW) == len(bO) == inl_ball.sum()
    # the same inliers as the camera's: no second hypothesis (its feature terms would be the same)
    assert _ball_hypothesis(fW[~static], fO[~static], np.ones((~static).sum(), bool), TrackingConfig(),
                            np.random.default_rng(0)) is None


def _box_scene(seed: int):
    """A 12 × 8 × 6 cm box model (three faces seen, 3 mm spacing, O at its centre) and a frame of it at pose X_true
    (W = O turned 20° about z and moved 5 mm) with 0.5 mm of depth noise; feature correspondences: 40 keypoints
    on the seen faces, exact in ``right``, in ``wrong`` with the W side moved 6 mm along the long face (x of O)."""
    rng = np.random.default_rng(seed)
    h = np.array([0.06, 0.04, 0.03])
    g = np.arange(-1.0, 1.0001, 0.05)
    Q, N = [], []
    for ax, (u, v) in ((0, (1, 2)), (1, (0, 2)), (2, (0, 1))):
        uu, vv = np.meshgrid(g * h[u], g * h[v])
        P = np.zeros((uu.size, 3))
        P[:, u], P[:, v], P[:, ax] = uu.ravel(), vv.ravel(), -h[ax]
        n = np.zeros(3)
        n[ax] = -1.0
        Q.append(P)
        N.append(np.tile(n, (len(P), 1)))
    Q, N = np.concatenate(Q), np.concatenate(N)
    model = SimpleNamespace(tree=cKDTree(Q), Q=Q, N=N)
    X_true = make_X(so3_exp(np.radians(20.0) * np.array([0.0, 0.0, 1.0])), np.array([0.005, 0.0, 0.0]))
    P_W = Q @ X_true[:3, :3].T + X_true[:3, 3] + rng.normal(scale=0.0005, size=Q.shape)
    N_W = N @ X_true[:3, :3].T
    k = rng.choice(len(Q), 40, replace=False)
    fO = Q[k]
    fW_right = fO @ X_true[:3, :3].T + X_true[:3, 3]
    fW_wrong = fW_right + X_true[:3, :3] @ np.array([0.006, 0.0, 0.0])
    return model, P_W, N_W, X_true, (fW_right, fO), (fW_wrong, fO)


def test_the_depth_score_picks_the_hypothesis_that_fits_the_frame():
    model, P_W, N_W, X_true, right, wrong = _box_scene(0)
    cfg = TrackingConfig()
    # the first consensus is wrong (6 mm along the long face): alone, ICP with its terms is pulled off the truth
    start_wrong = make_X(X_true[:3, :3], X_true[:3, 3] + X_true[:3, :3] @ np.array([0.006, 0.0, 0.0]))
    alone, by = _register_candidates(P_W, N_W, [start_wrong], wrong[0], wrong[1], None, model, cfg, ICP_KW)
    assert not by and pose_distance(alone.X_WO, X_true)[0] > 0.002
    # with the right consensus as the second hypothesis, its start wins on the depth points' score
    best, by = _register_candidates(P_W, N_W, [start_wrong], wrong[0], wrong[1], (X_true, right[0], right[1]),
                                    model, cfg, ICP_KW)
    assert by and pose_distance(best.X_WO, X_true)[0] < 0.001
    # and the other way round: a wrong second hypothesis does not displace the right first one
    best, by = _register_candidates(P_W, N_W, [X_true], right[0], right[1], (start_wrong, wrong[0], wrong[1]),
                                    model, cfg, ICP_KW)
    assert not by and pose_distance(best.X_WO, X_true)[0] < 0.001


def test_config_refuses_non_bool():
    assert TrackingConfig().track_ransac_both is False
    for v in (1, "yes", None):
        with pytest.raises(ValueError):
            TrackingConfig(track_ransac_both=v)


def _plane_scene(seed: int):
    """One 12 × 8 cm face (the depth points fix nothing along it) 0.8 m in front of the camera, at X_true = O moved 3 mm
    along the face; 60 ORB matches of which 45 agree with X_true and 15 were kept by the second consensus only, 6 mm
    off along the face (keypoints that did not follow the surface)."""
    rng = np.random.default_rng(seed)
    g = np.arange(-1.0, 1.0001, 0.05)
    uu, vv = np.meshgrid(0.06 * g, 0.04 * g)
    Q = np.stack([uu.ravel(), vv.ravel(), np.zeros(uu.size)], 1)
    N = np.tile([0.0, 0.0, -1.0], (len(Q), 1))
    model = SimpleNamespace(tree=cKDTree(Q), Q=Q, N=N)
    X_true = make_X(np.eye(3), np.array([0.003, 0.0, 0.0]))
    P_W = Q + X_true[:3, 3] + rng.normal(scale=0.0005, size=Q.shape) * [0, 0, 1]
    k = rng.choice(len(Q), 60, replace=False)
    fO = Q[k]
    fW = fO + X_true[:3, 3]
    fW[45:] += [0.006, 0.0, 0.0]
    X_CW = make_X(np.eye(3), np.array([0.0, 0.0, 0.8]))
    return model, P_W, N.copy(), X_true, fW, fO, X_CW


def test_reproj_score_picks_the_pose_most_matches_agree_with():
    model, P_W, N_W, X_true, fW, fO, X_CW = _plane_scene(0)
    X_off = make_X(np.eye(3), X_true[:3, 3] + [0.006, 0.0, 0.0])
    cfg = TrackingConfig(track_ransac_px=2.0, track_ransac_both=True, track_ransac_both_score="reproj")
    matches = (fW, fO, K, X_CW)
    # first the consensus of the 15 off matches, then the 45 right ones as the second hypothesis, and the reverse
    for first, second, want_other in (((X_off, fW[45:], fO[45:]), (X_true, fW[:45], fO[:45]), True),
                                      ((X_true, fW[:45], fO[:45]), (X_off, fW[45:], fO[45:]), False)):
        best, by = _register_candidates(P_W, N_W, [first[0]], first[1], first[2], second, model, cfg, ICP_KW,
                                        matches=matches)
        assert by == want_other and pose_distance(best.X_WO, X_true)[0] < 0.001
    # the plane fixes nothing along it: both results fit the depth points alike, so the depth score cannot choose
    depth = TrackingConfig(track_ransac_px=2.0, track_ransac_both=True)
    a, _ = _register_candidates(P_W, N_W, [X_off], fW[45:], fO[45:], None, model, depth, ICP_KW)
    b, _ = _register_candidates(P_W, N_W, [X_true], fW[:45], fO[:45], None, model, depth, ICP_KW)
    assert abs(a.inlier_frac - b.inlier_frac) < 0.01 and abs(a.rmse - b.rmse) < 0.0002
    assert pose_distance(a.X_WO, b.X_WO)[0] > 0.004


def test_config_refuses_unknown_score():
    assert TrackingConfig().track_ransac_both_score == "depth"
    with pytest.raises(ValueError):
        TrackingConfig(track_ransac_both_score="features")
