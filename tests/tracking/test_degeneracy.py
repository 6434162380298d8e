"""Degeneracy-aware registration (service.tracking.geometry.degenerate_map, icp(w_feat_degen=...)).

A body of revolution turned about its own axis leaves its point-to-plane residuals unchanged: ICP cannot see
that rotation, feature correspondences can. Feature terms restricted to the weak directions must fix it, and
on a shape without weak directions (a box corner) they must not enter at all, so that biased features cannot
pull a well-conditioned fit."""

import numpy as np
from scipy.spatial import cKDTree

from service.tracking.geometry import degeneracy, degenerate_map, icp
from service.transforms import X_inv, make_X, pose_errors, so3_exp


def _cylinder(rng, n=3000, r=0.035, half=0.1):
    """Closed cylinder along x: side and two caps."""
    th = rng.uniform(-np.pi, np.pi, n)
    x = rng.uniform(-half, half, n)
    P = np.c_[x, r * np.cos(th), r * np.sin(th)]
    N = np.c_[np.zeros(n), np.cos(th), np.sin(th)]
    nc = n // 8
    rr, tc = r * np.sqrt(rng.uniform(0, 1, nc)), rng.uniform(-np.pi, np.pi, nc)
    for sgn in (-1.0, 1.0):
        P = np.r_[P, np.c_[np.full(nc, sgn * half), rr * np.cos(tc), rr * np.sin(tc)]]
        N = np.r_[N, np.tile([sgn, 0.0, 0.0], (nc, 1))]
    return P, N


def _box(rng, n=3000, h=0.05):
    P, N = [], []
    for ax in range(3):
        for sgn in (-1.0, 1.0):
            q = rng.uniform(-h, h, (n // 6, 3))
            q[:, ax] = sgn * h
            nn = np.zeros((n // 6, 3))
            nn[:, ax] = sgn
            P.append(q)
            N.append(nn)
    return np.concatenate(P), np.concatenate(N)


def _visible(P, N, cam):
    return ((cam - P) * N).sum(1) > 0


def test_degeneracy_eigenvalues():
    rng = np.random.default_rng(0)
    P, N = _cylinder(rng)
    vis = _visible(P, N, np.array([0.3, 0.0, 0.5]))  # side and one cap
    lam = degeneracy(P[vis], N[vis])
    assert lam[0] < 1e-6 and lam[1] > 0.02, lam  # exactly one weak direction: the roll about the axis
    P, N = _box(rng)
    vis = _visible(P, N, np.array([0.4, 0.3, 0.5]))
    assert degeneracy(P[vis], N[vis])[0] > 0.05  # three faces: nothing weak
    Hb = np.hstack([np.cross(P[vis], N[vis]), N[vis]])
    assert degenerate_map(Hb.T @ Hb, float(vis.sum()), P[vis], 0.02) is None


def _register(P_O, N_O, X_true, X_start, feat_O, feat_err, **kw):
    """Observed points (the visible side) in W under X_true, features observed with an error feat_err (3,)."""
    cam_W = np.array([0.8, 0.0, 0.6])
    P_W = P_O @ X_true[:3, :3].T + X_true[:3, 3]
    N_W = N_O @ X_true[:3, :3].T
    vis = _visible(P_W, N_W, cam_W)
    fW = feat_O @ X_true[:3, :3].T + X_true[:3, 3] + feat_err
    return icp(P_W[vis], X_start, cKDTree(P_O), P_O, N_O, feat_W=fW, feat_O=feat_O, iters=15, dist0=0.02,
               dist_min=0.004, **kw)


def test_features_fix_the_roll_of_a_body_of_revolution():
    rng = np.random.default_rng(1)
    P, N = _cylinder(rng)
    X_true = make_X(so3_exp([0.3, 0.0, 0.0]), [0.5, 0.0, 0.1])  # rolled 17° about its axis (x)
    X_start = X_true @ make_X(so3_exp([np.radians(8), 0, 0]), [0, 0, 0])  # 8° more roll
    F = P[:3000][rng.choice(3000, 200, replace=False)]  # on the side (textured label)
    F = F[_visible(F @ X_true[:3, :3].T + X_true[:3, 3], (F * [0, 1, 1] / 0.035) @ X_true[:3, :3].T,
                   np.array([0.8, 0.0, 0.6]))]
    noise = 0.001 * rng.normal(size=F.shape)
    r0 = _register(P, N, X_true, X_start, F, noise, w_feat=0.0, w_feat_degen=0.0)
    r1 = _register(P, N, X_true, X_start, F, noise, w_feat=0.0, w_feat_degen=1.0)
    _, e0 = pose_errors(r0.X_WO[None], X_true[None])
    et, e1 = pose_errors(r1.X_WO[None], X_true[None])
    assert np.degrees(e0[0]) > 4.0, np.degrees(e0)  # shape alone: most of the 8° roll error stays
    assert np.degrees(e1[0]) < 1.0 and et[0] < 0.002, (np.degrees(e1), et)


def test_biased_features_do_not_move_a_well_conditioned_fit():
    rng = np.random.default_rng(2)
    P, N = _box(rng)
    X_true = make_X(so3_exp([0.1, -0.2, 0.3]), [0.5, 0.0, 0.1])
    X_start = X_true @ make_X(so3_exp([0.02, 0.01, -0.02]), [0.003, -0.002, 0.002])
    F = P[rng.choice(len(P), 150, replace=False)]
    bias = np.array([0.004, 0.0, 0.0])  # every feature 4 mm off (keypoints at edges, depth smear)
    r_full = _register(P, N, X_true, X_start, F, bias, w_feat=1.0, w_feat_degen=0.0)
    r_deg = _register(P, N, X_true, X_start, F, bias, w_feat=0.0, w_feat_degen=1.0)
    t_full, _ = pose_errors(r_full.X_WO[None], X_true[None])
    t_deg, r = pose_errors(r_deg.X_WO[None], X_true[None])
    assert t_full[0] > 0.001, t_full  # features in all directions pull the box
    assert t_deg[0] < 0.0003 and np.degrees(r[0]) < 0.2, (t_deg, np.degrees(r))
