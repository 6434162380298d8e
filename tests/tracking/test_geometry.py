"""Registration primitives against naive references, and the velocity filter on a known motion."""

import numpy as np
from scipy.optimize import minimize
from scipy.spatial import cKDTree

from service.tracking.geometry import icp, kabsch, ransac_rigid
from service.tracking.velocity import velocities
from service.transforms import X_inv, make_X, pose_errors, so3_exp, so3_log


def _naive_rigid_fit(A, B):
    """Minimise Σ‖R(r) a + t − b‖² over rotation vector r and t with a generic optimiser."""
    def f(x):
        return np.sum((A @ so3_exp(x[:3]).T + x[3:] - B) ** 2)

    x = minimize(f, np.zeros(6), method="BFGS", options={"gtol": 1e-12}).x
    return make_X(so3_exp(x[:3]), x[3:])


def test_kabsch_matches_naive_optimiser():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(30, 3)) * 0.05
    X = make_X(so3_exp([0.3, -0.2, 0.4]), [0.02, 0.01, -0.03])
    B = A @ X[:3, :3].T + X[:3, 3] + rng.normal(size=A.shape) * 1e-3
    Xk = kabsch(A, B)
    Xn = _naive_rigid_fit(A, B)
    dt, dr = pose_errors(Xk[None], Xn[None])
    assert dt[0] < 1e-5 and dr[0] < 1e-4
    assert abs(np.linalg.det(Xk[:3, :3]) - 1) < 1e-9


def test_kabsch_batched_equals_loop():
    rng = np.random.default_rng(1)
    A, B = rng.normal(size=(5, 4, 3)), rng.normal(size=(5, 4, 3))
    Xb = kabsch(A, B)
    for i in range(5):
        np.testing.assert_allclose(Xb[i], kabsch(A[i], B[i]), atol=1e-10)


def test_ransac_rejects_outliers():
    rng = np.random.default_rng(2)
    A = rng.uniform(-0.05, 0.05, size=(60, 3))
    X = make_X(so3_exp([0.0, 0.5, 0.1]), [0.1, 0.0, 0.02])
    B = A @ X[:3, :3].T + X[:3, 3]
    B[:20] = rng.uniform(-0.1, 0.1, size=(20, 3))  # a third wrong matches
    Xr, inl = ransac_rigid(A, B, thr=0.003, rng=rng)
    assert inl[20:].all() and inl[:20].sum() <= 1
    dt, dr = pose_errors(Xr[None], X[None])
    assert dt[0] < 1e-6 and dr[0] < 1e-6


def _box_surface(n=3000, ext=(0.08, 0.05, 0.04), seed=0):
    rng = np.random.default_rng(seed)
    e = np.array(ext) / 2
    P, N = [], []
    for ax in range(3):
        for sgn in (-1, 1):
            p = rng.uniform(-e, e, size=(n // 6, 3))
            p[:, ax] = sgn * e[ax]
            nn = np.zeros((n // 6, 3))
            nn[:, ax] = sgn
            P.append(p)
            N.append(nn)
    return np.concatenate(P), np.concatenate(N)


def test_icp_recovers_pose_of_partial_view():
    Q, Nq = _box_surface()
    X_true = make_X(so3_exp([0.05, -0.08, 0.1]), [0.5, 0.1, 0.3])  # X_WO
    view = (Nq @ np.array([0.3, -0.5, 0.8])) > 0  # three faces seen by a camera
    P_W = Q[view][::3] @ X_true[:3, :3].T + X_true[:3, 3]
    P_W = P_W + np.random.default_rng(3).normal(size=P_W.shape) * 5e-4
    start = X_true @ make_X(so3_exp([0.06, 0.03, -0.05]), [0.012, -0.008, 0.01])
    r = icp(P_W, start, cKDTree(Q), Q, Nq, iters=25)
    dt, dr = pose_errors(r.X_WO[None], X_true[None])
    assert dt[0] < 1.5e-3 and np.degrees(dr[0]) < 0.5, (dt, np.degrees(dr))
    assert r.inlier_frac > 0.95


def test_velocities_of_known_screw_motion():
    t = np.arange(40) / 30.0
    w_body = np.array([0.3, -0.2, 1.0])
    v_world = np.array([0.1, 0.05, 0.0])
    X = np.stack([make_X(so3_exp(w_body * ti), np.array([0.4, 0.0, 0.05]) + v_world * ti) for ti in t])
    v, w = velocities(t, X)
    np.testing.assert_allclose(v[2:-2], np.tile(v_world, (36, 1)), atol=1e-6)
    np.testing.assert_allclose(w[2:-2], np.tile(w_body, (36, 1)), atol=1e-6)
    # the median filter removes a single-frame pose spike
    Xs = X.copy()
    Xs[20, :3, 3] += 0.02
    v2, _ = velocities(t, Xs)
    assert np.abs(v2[5:-5] - v_world).max() < 1e-6


def test_velocities_use_real_timestamps():
    t = np.cumsum(np.r_[0, np.full(9, 0.03), np.full(10, 0.05)])
    X = np.stack([make_X(np.eye(3), [0.2 * ti, 0, 0]) for ti in t])
    v, _ = velocities(t, X)
    np.testing.assert_allclose(v[:, 0], 0.2, atol=1e-9)


def test_rotate_all_and_matcher_equal_their_references():
    """RANSAC's residual kernel against the einsum it replaces (same sums; equal bit for bit on the machine the
    benchmark runs on, within rounding elsewhere), and the ratio-test matcher against BFMatcher.knnMatch's pairs,
    also on descriptors full of ties."""
    import cv2

    from service.tracking.geometry import _rotate_all
    from service.tracking.tracker import _match

    rng = np.random.default_rng(5)
    R = np.stack([so3_exp(rng.normal(size=3)) for _ in range(20)])
    A = rng.normal(0.3, 0.2, (37, 3))
    np.testing.assert_allclose(_rotate_all(R, A), np.einsum("mij,nj->mni", R, A), rtol=0, atol=1e-15)

    def knn_pairs(da, db):
        out = [(p[0].queryIdx, p[0].trainIdx) for p in cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(da, db, k=2)
               if len(p) == 2 and p[0].distance < 0.8 * p[1].distance and p[0].distance < 64]
        return np.array(out, int).reshape(-1, 2)

    for hi in (256, 3, 2):  # few distinct byte values: many equal distances
        for _ in range(10):
            da = rng.integers(0, hi, (int(rng.integers(2, 60)), 32), dtype=np.uint8)
            db = rng.integers(0, hi, (int(rng.integers(2, 60)), 32), dtype=np.uint8)
            db[: min(len(da), len(db)) // 2] = da[: min(len(da), len(db)) // 2] ^ (rng.random((min(len(da), len(db)) // 2, 32)) < 0.05).astype(np.uint8)
            np.testing.assert_array_equal(_match(da, db), knn_pairs(da, db))
    assert _match(None, db).shape == (0, 2) and _match(da[:1], db).shape == (0, 2)
