"""Keyframe bundle adjustment (service.tracking.posegraph) on exact synthetic keyframes: partial views of a box
seen under known poses, with perturbed starting poses; the joint refinement must recover the true poses."""

import numpy as np

from service.tracking.posegraph import bundle_adjust
from service.transforms import X_inv, make_X, pose_errors, so3_exp


def _box_surface(rng, size=(0.10, 0.06, 0.15), n=6000):
    """Points (n,3) and outward normals on the surface of a box centred at the origin."""
    half = np.array(size) / 2
    area = np.array([size[1] * size[2], size[0] * size[2], size[0] * size[1]])
    axis = rng.choice(3, n, p=area / area.sum())
    sign = rng.choice([-1.0, 1.0], n)
    P = rng.uniform(-half, half, (n, 3))
    P[np.arange(n), axis] = sign * half[axis]
    N = np.zeros((n, 3))
    N[np.arange(n), axis] = sign
    return P, N


def _views(rng, n_kf=6, noise=0.0005):
    P_O, N_O = _box_surface(rng)
    cam = np.array([0.5, -0.6, 0.6])  # camera position in W (views see two or three faces)
    X_true, P_W, N_W = [], [], []
    rv = np.zeros(3)
    for k in range(n_kf):
        if k:
            rv = rv + np.radians(18) * rng.normal(size=3) / np.sqrt(3)
        X = make_X(so3_exp(rv), [0.01 * k, 0.0, 0.05])
        p = P_O @ X[:3, :3].T + X[:3, 3]
        n = N_O @ X[:3, :3].T
        vis = ((cam - p) * n).sum(1) > 0.2 * np.linalg.norm(cam - p, axis=1)
        sel = rng.choice(np.nonzero(vis)[0], 800, replace=False)
        X_true.append(X)
        P_W.append(p[sel] + noise * rng.normal(size=(800, 3)))
        N_W.append(n[sel])
    return np.stack(X_true), P_W, N_W


def test_bundle_adjustment_recovers_keyframe_poses():
    rng = np.random.default_rng(3)
    X_WO, P_W, N_W = _views(rng)
    X_OW_true = np.stack([X_inv(x) for x in X_WO])
    X0 = X_OW_true.copy()
    for k in range(1, len(X0)):  # keyframe 0 defines O and is exact
        X0[k] = make_X(so3_exp(np.radians(3.0) * rng.normal(size=3) / np.sqrt(3)),
                       0.004 * rng.normal(size=3) / np.sqrt(3)) @ X0[k]
    et0, er0 = pose_errors(X0, X_OW_true)
    assert np.degrees(er0[1:]).mean() > 2.0  # the start is really off
    res = bundle_adjust(X0, P_W, N_W, iters=10, dist0=0.02, dist_min=0.004)
    np.testing.assert_allclose(res.X_OW[0], X0[0])  # gauge: keyframe 0 fixed
    et, er = pose_errors(res.X_OW, X_OW_true)
    assert np.degrees(er).max() < 0.5, np.degrees(er)  # from 3° / 4 mm, 0.5 mm noise
    assert et.max() < 0.001, et
    assert res.n_pairs > len(X0) and res.cost < res.cost0
