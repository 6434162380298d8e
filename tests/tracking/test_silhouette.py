"""Silhouette term (service.tracking.silhouette): a box ray-cast analytically (240x180), its model only the two
faces a camera sees; the mask fixes the slide along their common edge that point-to-plane ICP leaves free, and an
occluder's edge is not taken for the outline."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from service.tracking import TrackingConfig
from service.tracking.silhouette import make_view, refine, rim_points, silhouette_terms
from service.transforms import X_inv, make_X

HALF = np.array([0.06, 0.04, 0.025])  # box half extents in O
K = np.array([[200.0, 0, 120], [0, 200.0, 90], [0, 0, 1]])


def _camera(c=(0.0, -0.40, 0.30)) -> np.ndarray:
    """X_WC of a camera at c looking at the origin (x_C horizontal)."""
    c = np.asarray(c, float)
    z = -c / np.linalg.norm(c)
    x = np.cross(z, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_X(np.stack([x, y, z], 1), c)


def _render(X_WO, X_WC, occluder_u=None):
    """Depth (H,W) and mask of the box; with occluder_u, the columns u >= occluder_u show a plate 0.1 m in front
    of the camera... at depth 0.3 m (in front of the box) instead."""
    H, W = 180, 240
    v, u = np.mgrid[0:H, 0:W]
    d_C = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u, float)], -1).reshape(-1, 3)
    X_OC = X_inv(X_WO) @ X_WC
    o = X_OC[:3, 3]
    d = d_C @ X_OC[:3, :3].T
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-HALF - o) / d
        t2 = (HALF - o) / d
    tmin = np.nanmax(np.minimum(t1, t2), 1)
    tmax = np.nanmin(np.maximum(t1, t2), 1)
    hit = (tmax >= tmin) & (tmin > 0)
    depth = np.where(hit, tmin, 0.0).reshape(H, W)  # d_C has z = 1: t is the camera depth
    mask = hit.reshape(H, W)
    bg = 0.9  # a wall behind
    depth = np.where(mask, depth, bg)
    if occluder_u is not None:
        occ = u >= occluder_u
        mask = mask & ~occ
        depth = np.where(occ, 0.3, depth)
    return depth.astype(np.float32), mask


def _faces(n=40):
    """Points and normals (O) of the top (+z) and front (-y) faces."""
    a = np.linspace(-1, 1, n)
    A, B = np.meshgrid(a, a)
    top = np.c_[A.ravel() * HALF[0], B.ravel() * HALF[1], np.full(A.size, HALF[2])]
    front = np.c_[A.ravel() * HALF[0], np.full(A.size, -HALF[1]), B.ravel() * HALF[2]]
    P = np.concatenate([top, front])
    N = np.concatenate([np.tile([0, 0, 1.0], (len(top), 1)), np.tile([0, -1.0, 0], (len(front), 1))])
    return P, N


def test_silhouette_gradient_matches_finite_differences():
    X_WC = _camera()
    depth, mask = _render(np.eye(4), X_WC)
    view = make_view(depth, mask, K, X_WC)
    Q, _ = _faces()
    X_OW = make_X(np.eye(3), np.array([0.008, 0.003, -0.002]))  # points partly outside
    _, g, c0, n = silhouette_terms(Q, X_OW, view, huber_px=100.0, max_px=50.0)
    assert n > 50
    from service.tracking.geometry import _exp_se3

    num = np.zeros(6)
    for k in range(6):
        e = np.zeros(6)
        e[k] = 2e-5 if k < 3 else 1e-5
        cp = silhouette_terms(Q, _exp_se3(e) @ X_OW, view, huber_px=100.0, max_px=50.0)[2]
        cm = silhouette_terms(Q, _exp_se3(-e) @ X_OW, view, huber_px=100.0, max_px=50.0)[2]
        num[k] = (cp - cm) / (2 * e[k])
    assert np.allclose(g, num, rtol=0.15, atol=0.05 * np.abs(num).max())


def test_silhouette_fixes_the_slide_along_the_edge():
    X_WC = _camera()
    X_WO = np.eye(4)
    depth, mask = _render(X_WO, X_WC)
    view = make_view(depth, mask, K, X_WC)
    Q, N = _faces()
    tree = cKDTree(Q)
    # the frame sees the middle of both faces only (the ends occluded): nothing in the depth fixes x
    P_O = _faces(33)[0]  # another sampling than the model's
    P_W = P_O[np.abs(P_O[:, 0]) < 0.03]  # X_WO = I
    start = make_X(np.eye(3), np.array([0.006, 0.0, 0.0]))
    r0 = refine(P_W, start, tree, Q, N, Q, view, w_sil=0.0, iters=8)
    r1 = refine(P_W, start, tree, Q, N, Q, view, w_sil=1.0, iters=8)
    assert abs(r0.X_WO[0, 3] - 0.006) < 1e-3  # depth alone: the slide stays
    assert np.linalg.norm(r1.X_WO[:3, 3]) < 1e-3  # with the silhouette: back within 1 mm
    assert r1.inlier_frac > 0.95


def _slid_along_the_line_of_sight():
    """The camera looks along the top/front edge (x) from the +x side; the model's points near the middle, started
    6 mm along x: (X_WC, depth, mask, view, kd-tree of the model, model points, normals, points, start pose)."""
    X_WC = _camera((0.35, -0.12, 0.25))
    depth, mask = _render(np.eye(4), X_WC)
    view = make_view(depth, mask, K, X_WC)
    Q, N = _faces()
    P_O = _faces(33)[0]
    return (X_WC, depth, mask, view, cKDTree(Q), Q, N, P_O[np.abs(P_O[:, 0]) < 0.03],
            make_X(np.eye(3), np.array([0.006, 0.0, 0.0])))


def test_points_in_front_of_the_seen_surface_fix_a_slide_along_the_line_of_sight():
    # the camera looks along the top/front edge (x) from the +x side: a slide along x hardly moves the outline,
    # but the model's top and front faces then stick out in front of the +x end face the camera sees
    _, _, _, view, tree, Q, N, P_W, start = _slid_along_the_line_of_sight()
    r0 = refine(P_W, start, tree, Q, N, Q, view, w_sil=0.0, iters=8)
    r1 = refine(P_W, start, tree, Q, N, Q, view, w_sil=0.0, w_front=1.0, iters=8)
    assert abs(r0.X_WO[0, 3] - 0.006) < 1e-3
    assert np.linalg.norm(r1.X_WO[:3, 3]) < 1.5e-3
    # at the true pose the term is (nearly) silent
    r2 = refine(P_W, np.eye(4), tree, Q, N, Q, view, w_sil=1.0, w_front=1.0, iters=8)
    assert np.linalg.norm(r2.X_WO[:3, 3]) < 1e-3


def test_occluder_edge_is_not_an_outline():
    X_WC = _camera()
    X_WO = np.eye(4)
    depth, mask = _render(X_WO, X_WC, occluder_u=130)  # a plate in front hides the +x end of the box
    assert mask.any() and not mask[:, 130:].any()
    view = make_view(depth, mask, K, X_WC)
    Q, N = _faces()
    tree = cKDTree(Q)
    P_O = _faces(33)[0]
    P_W = P_O[np.abs(P_O[:, 0]) < 0.03]
    r = refine(P_W, X_WO, tree, Q, N, Q, view, w_sil=1.0, iters=8)
    assert np.linalg.norm(r.X_WO[:3, 3]) < 1e-3  # the hidden end does not pull the box out from under the plate
    r_blind = refine(P_W, X_WO, tree, Q, N, Q, view, w_sil=1.0, iters=8, occ_margin=10.0)  # no occlusion test
    assert r_blind.X_WO[0, 3] < -0.002


def test_rim_points_keep_the_outline_and_drop_mixed_pixels():
    X_WC = _camera()
    depth, mask = _render(np.eye(4), X_WC)
    mixed = depth.copy()
    ring = mask & ~np.roll(mask, 1, axis=1)  # left outline column of the box
    mixed[ring] = 0.5 * (depth[ring] + 0.9)  # blends of the box and the wall behind
    R = rim_points(mixed, mask, K, X_WC, 2, -1.0, 0.0)
    assert len(R) > 50
    # every rim point lies on the box surface (none of the blends)
    d_out = np.max(np.abs(R) - HALF, axis=1)
    assert np.all(d_out < 2e-3)
    assert rim_points(depth, mask, K, X_WC, 0, -1.0, 0.0).shape == (0, 3)


def test_config_validation():
    with pytest.raises(ValueError):
        TrackingConfig(sil_stages="track,ba")
    with pytest.raises(ValueError):
        TrackingConfig(w_sil=-1.0)
    assert TrackingConfig(w_sil=1.0).stage_set("sil_stages") == {"track", "final"}


def test_tracker_takes_only_small_corrections():
    from types import SimpleNamespace

    import service.tracking.tracker as tracker
    from service.tracking.geometry import IcpResult

    X_WC = _camera()
    depth, mask = _render(np.eye(4), X_WC)
    session = SimpleNamespace(K=K, X_WC=X_WC, depth=lambda i: depth, mask=lambda i: mask)
    Q, N = _faces()
    model = tracker.ObjectModel.build(0.003, [(Q, N)])
    P_O = _faces(33)[0]
    P_W = P_O[np.abs(P_O[:, 0]) < 0.03]
    cfg = TrackingConfig(w_sil=1.0, sil_iters=8)
    for dx, moved in ((0.004, True), (0.010, False)):  # 10 mm: beyond sil_max_step = 6 mm
        X0 = make_X(np.eye(3), np.array([dx, 0.0, 0.0]))
        r = IcpResult(X_WO=X0, inlier_frac=1.0, rmse=0.0005, n_inliers=len(P_W), nn_dist=np.zeros(len(P_W)))
        out = tracker._sil_refine(session, 0, P_W, r, model, Q, cfg)
        assert (abs(out.X_WO[0, 3]) < 1.5e-3) == moved
        assert (out is r) == (not moved)


def test_weak_directions_only_and_free_space_gate():
    from types import SimpleNamespace

    import service.tracking.tracker as tracker
    from service.tracking.geometry import IcpResult
    from service.tracking.silhouette import front_violations, weak_projector

    X_WC, depth, mask, view, tree, Q, N, P_W, start = _slid_along_the_line_of_sight()
    # two faces seen: the slide along x is weak, the free-space term restricted to it still removes it
    r1 = refine(P_W, start, tree, Q, N, Q, view, w_sil=1.0, w_front=1.0, iters=8, weak_ratio=0.05)
    assert np.linalg.norm(r1.X_WO[:3, 3]) < 1.5e-3
    # the gate: at the slid pose the model sticks out in front of the end face, at the true pose it does not
    nv, n = front_violations(Q, X_inv(start), view, 0.003)
    assert n > 100 and nv > 0.04 * n  # the ends of the top and front faces (5 %)
    nv0, n0 = front_violations(Q, np.eye(4), view, 0.003)
    assert n0 > 100 and nv0 < 0.01 * n0
    # the +x end face seen as well: depth fixes every direction, the terms may not move the pose
    a = np.linspace(-1, 1, 33)
    A, B = np.meshgrid(a, a)
    end = np.c_[np.full(A.size, HALF[0]), A.ravel() * HALF[1], B.ravel() * HALF[2]]
    Q3 = np.concatenate([Q, end])
    N3 = np.concatenate([N, np.tile([1.0, 0, 0], (len(end), 1))])
    P3 = np.concatenate([P_W, end])
    H = np.zeros((6, 6))
    from service.tracking.geometry import _cross

    J = np.hstack([_cross(P3, N3[cKDTree(Q3).query(P3)[1]]), N3[cKDTree(Q3).query(P3)[1]]])
    H = J.T @ J
    assert weak_projector(H, 0.05, 0.05) is None
    Jtwo = np.hstack([_cross(P_W, N[tree.query(P_W)[1]]), N[tree.query(P_W)[1]]])
    M = weak_projector(Jtwo.T @ Jtwo, 0.05, 0.05)
    assert M is not None and abs(M[3, 3] - 1.0) < 0.05  # x translation kept
    off = make_X(np.eye(3), np.array([0.0, 0.0, 0.004]))  # a 4 mm error depth sees
    r3 = refine(P3, off, cKDTree(Q3), Q3, N3, Q3, view, w_sil=1.0, w_front=1.0, iters=8, weak_ratio=0.05)
    assert np.allclose(r3.X_WO, off)
    # tracker: with the gate on, a frame without free-space violations keeps its ICP pose
    session = SimpleNamespace(K=K, X_WC=X_WC, depth=lambda i: depth, mask=lambda i: mask)
    model = tracker.ObjectModel.build(0.003, [(Q, N)])
    cfg = TrackingConfig(w_sil=1.0, sil_iters=8, sil_gate_frac=0.03, sil_gate_margin=0.003)
    X0 = make_X(np.eye(3), np.array([0.0005, 0.0, 0.0]))
    r = IcpResult(X_WO=X0, inlier_frac=1.0, rmse=0.0005, n_inliers=len(P_W), nn_dist=np.zeros(len(P_W)))
    assert tracker._sil_refine(session, 0, P_W, r, model, Q, cfg) is r
    r = IcpResult(X_WO=start, inlier_frac=1.0, rmse=0.0005, n_inliers=len(P_W), nn_dist=np.zeros(len(P_W)))
    assert np.linalg.norm(tracker._sil_refine(session, 0, P_W, r, model, Q, cfg).X_WO[:3, 3]) < 1.5e-3
    with pytest.raises(ValueError):
        TrackingConfig(sil_weak_len=0.0)


def test_smoothing_of_model_points_and_readings():
    from service.tracking.silhouette import smooth_front, smooth_points

    rng = np.random.default_rng(3)
    Q = np.c_[rng.uniform(-0.05, 0.05, (3000, 2)), rng.normal(0.0, 0.0015, 3000)]  # a noisy plane z = 0
    S = smooth_points(Q, 0.009)
    assert S[:, 2].std() < 0.4 * Q[:, 2].std()
    assert np.median(np.abs(S[:, :2] - Q[:, :2])) < 2e-4  # along the (nearly vertical) normal
    far = np.array([[1.0, 1.0, 1.0]])
    assert np.allclose(smooth_points(np.concatenate([Q, far]), 0.009)[-1], far)  # no neighbours: unchanged
    v, u = np.mgrid[0:40, 0:50]
    plane = (0.6 + 0.001 * u + 0.0005 * v).astype(np.float32)
    noisy = plane + rng.normal(0.0, 0.002, plane.shape).astype(np.float32)
    noisy[:, :5] = 0.0  # no reading
    f = smooth_front(noisy, 1)
    inner = (slice(2, -2), slice(7, -2))
    assert np.all(f[:, :5] == 0)
    assert np.abs(f[inner] - plane[inner]).std() < 0.5 * np.abs(noisy[inner] - plane[inner]).std()
