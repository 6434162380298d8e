"""The settled pose after a topple from the pre-fall model and the fall's physics (service.tracking.resettle)."""

import numpy as np

from service.tracking.resettle import (base_points, base_shift, face_offsets, find_fall, landing_pose,
                                      pose_consistent, reach_along)
from service.transforms import X_inv, make_X, pose_distance, se3_exp, se3_log, so3_exp

SIZE = np.array([0.07, 0.07, 0.185])  # a milk carton standing, its centre at the origin of O


def box_faces(step: float = 0.004, z_min: float = -1.0) -> tuple[np.ndarray, np.ndarray]:
    """Points (M,3) and outward normals of the box's surface in O, the faces' points below z_min left out."""
    P, N = [], []
    hs = SIZE / 2
    for ax in range(3):
        for sgn in (-1.0, 1.0):
            o = [a for a in range(3) if a != ax]
            g = np.stack(np.meshgrid(np.arange(-hs[o[0]], hs[o[0]] + 1e-9, step),
                                     np.arange(-hs[o[1]], hs[o[1]] + 1e-9, step)), -1).reshape(-1, 2)
            p = np.zeros((len(g), 3))
            p[:, o[0]], p[:, o[1]] = g[:, 0], g[:, 1]
            p[:, ax] = sgn * hs[ax]
            n = np.zeros((len(g), 3))
            n[:, ax] = sgn
            P.append(p)
            N.append(n)
    P, N = np.concatenate(P), np.concatenate(N)
    keep = P[:, 2] >= z_min
    return P[keep], N[keep]


def settled_truth(X_r: np.ndarray, table: float) -> np.ndarray:
    """The standing box X_r tipped by 90° about its bottom edge at +y (it falls toward +y, about the −x axis)."""
    h = np.array([-1.0, 0.0, 0.0])
    pivot = X_r[:3, 3] + np.array([0.0, SIZE[1] / 2, -SIZE[2] / 2])
    R = so3_exp(h * np.pi / 2)
    return make_X(R @ X_r[:3, :3], pivot + R @ (X_r[:3, 3] - pivot))


def test_landing_pose_from_the_upper_part_only():
    table = 0.0
    X_r = make_X(np.eye(3), np.array([0.4, 0.1, table + SIZE[2] / 2]))
    # the pre-fall model: what an elevated camera sees of the standing box, its upper part only (z > -1 cm in O)
    Q, Nq = box_faces(z_min=-0.01)
    vis = (Nq @ np.array([0.0, 1.0, 0.3])) > 0  # top and the +y face (the one that leads)
    Q, Nq = Q[vis], Nq[vis]
    rng = np.random.default_rng(3)
    Q = Q + rng.normal(0, 0.0008, Q.shape)
    truth = settled_truth(X_r, table)
    # the tip axis seen by the loop lags and is 6° off the true one; the turn so far was 30°
    h = so3_exp(np.array([0, 0, np.radians(6.0)])) @ np.array([-1.0, 0.0, 0.0])
    X, face = landing_pose(X_r, h, Q, Nq, table)
    assert face
    dt, da = pose_distance(X, truth)
    assert da < 1.0 and dt < 0.003, (da, dt)
    # a 90° turn about the seen axis through the model's centre (no edge, no face): far off
    Rn = so3_exp(h * np.pi / 2)
    naive = make_X(Rn @ X_r[:3, :3], X_r[:3, 3])
    assert pose_distance(naive, truth)[1] > 4.0 and pose_distance(naive, truth)[0] > 0.05


def test_face_offsets_and_reach_correct_a_slide():
    table = 0.0
    X_r = make_X(np.eye(3), np.array([0.0, 0.0, SIZE[2] / 2]))
    truth = settled_truth(X_r, table)
    Q, Nq = box_faces(z_min=0.0)  # upper half: both x faces, both y faces and the top
    # the settled frame sees the whole lying box from above: its points in W with normals facing up or toward +x
    P, Np = box_faces()
    Pw, Nw = P @ truth[:3, :3].T + truth[:3, 3], Np @ truth[:3, :3].T
    seen = (Nw @ np.array([0.5, 0.0, 1.0])) > 0.1
    Pw, Nw = Pw[seen], Nw[seen]
    off = truth.copy()
    off[:3, 3] += np.array([0.008, 0.0, 0.0])  # slid 8 mm along the x face's normal
    fixed = face_offsets(off, Q, Nq, Pw, Nw)
    assert pose_distance(fixed, truth)[0] < 0.001
    # along the tipping direction (+y after the fall: the top end leads) the model must reach the seen points
    short = truth.copy()
    short[:3, 3] -= np.array([0.0, 0.01, 0.0])
    assert pose_distance(reach_along(short, Q, Pw, np.array([0.0, 1.0, 0.0]), 0.03), truth)[0] < 0.002
    # never pulled back (the frame may see less than the whole object)
    far = truth.copy()
    far[:3, 3] += np.array([0.0, 0.01, 0.0])
    assert np.allclose(reach_along(far, Q, Pw, np.array([0.0, 1.0, 0.0]), 0.03), far)


def test_find_fall_of_a_topple_not_of_a_push():
    N = 60
    X = np.tile(np.eye(4), (N, 1, 1))
    h = np.array([np.cos(0.3), np.sin(0.3), 0.0])
    ang = np.zeros(N)
    ang[20:30] = np.linspace(0.5, 5.0, 10).cumsum()  # tipping starts slowly
    ang[30:34] = ang[29] + np.array([10.0, 22.0, 36.0, 50.0])  # the fall, then lands
    ang[34:] = ang[33]
    for i in range(N):
        X[i] = make_X(so3_exp(h * np.radians(ang[i])), np.zeros(3))
    tracked = np.ones(N, bool)
    tracked[32] = False  # lost at the landing
    assert find_fall(X, tracked, 38, 8.0, 2.0, 0.3, 8.0, 6) is None  # too early
    r, g0, f, hh = find_fall(X, tracked, 39, 8.0, 2.0, 0.3, 8.0, 6)
    assert f == 33 and r == 19 and g0 == 22 and hh @ h > 0.999  # g0: the first step over 2°
    assert find_fall(X, tracked, 40, 8.0, 2.0, 0.3, 8.0, 6) is None  # looked at once
    # a fast turn about the vertical (a push that spins the object) is no tip
    for i in range(N):
        X[i] = make_X(so3_exp(np.array([0, 0, 1.0]) * np.radians(ang[i])), np.zeros(3))
    assert find_fall(X, tracked, 39, 8.0, 2.0, 0.3, 8.0, 6) is None
    assert np.allclose(X_inv(X[0]), np.eye(4))


def test_no_leading_face_on_a_curved_body():
    from service.tracking.resettle import face_plane

    rng = np.random.default_rng(5)
    d = np.array([0.0, 1.0, 0.0])
    # an ellipsoid (egg-like, 3 x 3 x 4.5 cm half axes): normals within 30° of d exist, but on no plane
    u = rng.normal(size=(4000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    ax = np.array([0.03, 0.03, 0.045])
    P = u * ax
    N = P / ax**2
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    assert face_plane(P, N, d, np.cos(np.radians(30.0)), 0.03) is None
    Q, Nq = box_faces()
    n, off = face_plane(Q, Nq, d, np.cos(np.radians(30.0)), 0.03)
    assert n @ d > 0.999 and abs(off - SIZE[1] / 2) < 1e-3


def test_base_free_space_moves_a_short_join_forward():
    """The base of the upper part of a standing carton (never seen) lies under it on the table; after the topple it
    faces −f, and a join 9 mm short of the landing puts it where the frames see the table behind the carton: the
    least consistent shift is the 9 mm slide (a join already right is not moved)."""
    Q, _ = box_faces(z_min=0.0)  # the upper half only, as the pre-fall views show it
    X_r = make_X(so3_exp(np.array([0.0, 0.0, np.radians(20.0)])), np.array([0.1, 0.2, SIZE[2] / 2]))
    B = base_points(Q, X_r, 0.0)
    B_r = B @ X_r[:3, :3].T + X_r[:3, 3]
    assert len(B) > 100 and np.allclose(B_r[:, 2], 0.0, atol=1e-9)
    P_base = np.array([[x, y, -SIZE[2] / 2] for x in (-1, 1) for y in (-1, 1)]) * [SIZE[0] / 2, SIZE[1] / 2, 1.0]
    lo, hi = B[:, :2].min(0), B[:, :2].max(0)
    assert np.all(lo >= P_base[:, :2].min(0) + 0.004) and np.all(hi <= P_base[:, :2].max(0) - 0.004)  # inset
    X_pure = settled_truth(X_r, 0.0)  # the pure turn about the edge: the join without the slide
    f = np.array([0.0, 1.0, 0.0])
    X_true = X_pure.copy()
    X_true[:3, 3] += 0.009 * f  # the carton slid 9 mm on landing
    b_true = float(np.min((B @ X_true[:3, :3].T + X_true[:3, 3]) @ f))

    def seen(P):  # the frames see the table behind the landed carton's base
        return P @ f < b_true - 0.001

    s = base_shift(B @ X_pure[:3, :3].T + X_pure[:3, 3], seen, f, 0.03)
    assert 0.007 <= s <= 0.0095
    assert base_shift(B @ X_true[:3, :3].T + X_true[:3, 3], seen, f, 0.03) == 0.0


def test_refine_frames_validated():
    import pytest

    from service.tracking import TrackingConfig

    assert TrackingConfig().resettle_refine_frames >= 0
    with pytest.raises(ValueError, match="resettle_refine_frames"):
        TrackingConfig(resettle_refine_frames=-1)


def _box_surface(h, n=3000, seed=0):
    rng = np.random.default_rng(seed)
    P = rng.uniform(-h, h, (n, 3))
    ax = rng.integers(0, 3, n)
    P[np.arange(n), ax] = np.where(rng.random(n) < 0.5, -1, 1) * h[ax]
    return P


def _tipped(theta_deg, h):
    """Pose of a box (half extents h) standing on the table z = 0, turned by theta about its bottom edge
    y = +h_y, z = 0 (a topple toward +y)."""
    edge = np.array([0.0, h[1], 0.0])
    R = so3_exp(np.radians([-theta_deg, 0.0, 0.0]))
    c0 = np.array([0.0, 0.0, h[2]])  # centre of the standing box
    return make_X(R, edge + R @ (c0 - edge))


def test_se3_log_exp_roundtrip():
    X = make_X(so3_exp(np.array([0.3, -0.2, 0.5])), np.array([0.1, -0.05, 0.2]))
    w, u = se3_log(X)
    assert np.allclose(se3_exp(w, u), X, atol=1e-10)


def test_pose_consistent_rejects_a_pose_through_the_table():
    h = np.array([0.035, 0.035, 0.1])
    Q = _box_surface(h)
    assert pose_consistent(_tipped(90.0, h), Q, 0.0, None, 0.01, 0.02, 0.05)
    assert not pose_consistent(_tipped(110.0, h), Q, 0.0, None, 0.01, 0.02, 0.05)


def test_landed_face_flush_and_planar_registration():
    """A lying carton whose pose is tilted 2°/1.5° and lifted 4 mm is laid flush with the table: the tilts and height
    removed, the yaw and horizontal position kept; a 3° yaw and a 5 mm horizontal offset are then removed by the
    registration of its visible points in the motions of an object resting on the table; a 30° tilt is reported as
    such (not resting on that face)."""
    from service.tracking.resettle import flush_pose, landed_face, planar_register

    rng = np.random.default_rng(3)
    Q, N = box_faces(step=0.004)
    X_r = make_X(np.eye(3), np.array([0.5, 0.0, SIZE[2] / 2]))
    X_t = settled_truth(X_r, 0.0)
    X_t = make_X(so3_exp(np.array([0.0, 0.0, 0.5])) @ X_t[:3, :3], X_t[:3, 3])  # some yaw
    tilt = make_X(so3_exp(np.array([np.radians(2.0), np.radians(-1.5), 0.0])), np.array([0.0, 0.0, 0.004]))
    X_bad = tilt @ X_t
    face = landed_face(Q, N, X_bad, 0.0, base_n_O=np.array([0.0, 0.0, -1.0]), square_deg=5.0)
    assert face is not None
    F, n = face
    assert np.allclose(n, [0.0, 1.0, 0.0], atol=1e-6)  # the +y side, on which the carton fell
    X_f, ang = flush_pose(X_bad, F, n, 0.0)
    assert abs(ang - np.hypot(2.0, 1.5)) < 0.05
    assert np.allclose(X_f[:3, :3] @ n, [0.0, 0.0, -1.0], atol=1e-9)
    d_t, d_r = pose_distance(X_f, X_t)
    assert d_r < 0.05 and d_t < 0.003 and abs(X_f[2, 3] - X_t[2, 3]) < 1e-4
    _, big = flush_pose(make_X(so3_exp(np.array([np.radians(30.0), 0.0, 0.0])), np.zeros(3)) @ X_t, F, n, 0.0)
    assert abs(big - 30.0) < 0.1
    # visible points of the lying box (not its face on the table), noisy
    P = Q @ X_t[:3, :3].T + X_t[:3, 3]
    P = P[P[:, 2] > 0.003]
    P = P[rng.choice(len(P), 900, replace=False)] + rng.normal(0.0, 0.0008, (900, 3))
    off = make_X(so3_exp(np.array([0.0, 0.0, np.radians(3.0)])), np.array([0.004, -0.003, 0.0]))
    X_0 = X_t.copy()
    X_0[:3, :3] = off[:3, :3] @ X_t[:3, :3]
    X_0[:3, 3] = X_t[:3, 3] + off[:3, 3]
    d_t0, d_r0 = pose_distance(X_0, X_t)
    X_p = planar_register(P, X_0, Q, N)
    d_t1, d_r1 = pose_distance(X_p, X_t)
    assert d_r0 > 2.9 and d_t0 > 0.004
    assert d_r1 < 0.3 and d_t1 < 0.0015
    assert abs(X_p[2, 3] - X_0[2, 3]) < 1e-12  # the height and the tilts are kept
    assert np.allclose(X_p[:3, 2] @ [0.0, 0.0, 1.0], X_0[:3, 2] @ [0.0, 0.0, 1.0], atol=1e-12)


def test_flush_deg_validated():
    import pytest

    from service.tracking import TrackingConfig

    with pytest.raises(ValueError, match="resettle_flush_deg"):
        TrackingConfig(resettle_flush_deg=-1.0)
    assert TrackingConfig().resettle_flush_deg == 10.0


def test_no_flush_face_on_a_curved_body():
    """An egg-sized ellipsoid has no flat side and no flat face where it lies (so its settled stretch is left as it
    is); a box has both."""
    from service.tracking.resettle import face_plane, has_flat_side, landed_face

    rng = np.random.default_rng(5)
    u = rng.normal(size=(6000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    a = np.array([0.0325, 0.0325, 0.045])
    P = u * a
    N = u / a
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    assert not has_flat_side(P, N, np.array([0.0, 0.0, -1.0]))
    assert face_plane(P, N, np.array([0.0, 1.0, 0.0]), np.cos(np.radians(30.0)), 0.03) is None  # lying on its side
    Q, Nb = box_faces(step=0.004)
    assert has_flat_side(Q, Nb, np.array([0.0, 0.0, -1.0]))
    assert landed_face(Q, Nb, settled_truth(make_X(np.eye(3), np.array([0.5, 0.0, SIZE[2] / 2])), 0.0), 0.0) is not None


def _seen_points(X: np.ndarray, rng: np.random.Generator, n: int = 800, noise: float = 0.0008
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Points and normals (in W) of the lying box at pose X seen from above and the +x side (a camera's view: the
    faces whose normals point up or toward +x), n of them with depth noise along the normal."""
    Q, N = box_faces(step=0.003)
    P, Nw = Q @ X[:3, :3].T + X[:3, 3], N @ X[:3, :3].T
    vis = (Nw[:, 2] > 0.5) | (Nw[:, 0] > 0.5)
    P, Nw = P[vis], Nw[vis]
    k = rng.choice(len(P), n, replace=False)
    return P[k] + rng.normal(0.0, noise, (n, 1)) * Nw[k], Nw[k]


def test_still_fit_tells_a_resting_frame_from_a_turning_one():
    """Two noisy views of the lying box at rest: nearly all points match within 1 cm, median point-to-plane distance
    about the noise (< 1.2 mm); the box turned 10° about its long axis: the median goes over 2 mm or the matched
    fraction under 0.9; slid 15 mm along its long axis (every seen face slides in its own plane) it still fits (what
    the keypoint test of ``_rest_before`` is for); too few points: no fit."""
    from service.tracking.resettle import still_fit

    rng = np.random.default_rng(5)
    X_t = settled_truth(make_X(np.eye(3), np.array([0.5, 0.0, SIZE[2] / 2])), 0.0)
    P_i, N_i = _seen_points(X_t, rng)
    P_j, _ = _seen_points(X_t, rng)
    frac, d = still_fit(P_j, P_i, N_i)
    assert frac > 0.95 and d < 0.0012
    R = so3_exp(X_t[:3, 2] * np.radians(10.0))  # about the box's long axis (lying horizontal), through its centre
    frac10, d10 = still_fit(_seen_points(make_X(R @ X_t[:3, :3], X_t[:3, 3]), rng)[0], P_i, N_i)
    assert frac10 < 0.9 or d10 > 0.002
    slid = X_t.copy()
    slid[:3, 3] += 0.015 * X_t[:3, 2]
    frac_s, d_s = still_fit(_seen_points(slid, rng)[0], P_i, N_i)
    assert frac_s > 0.9 and d_s < 0.0015
    assert still_fit(P_j[:5], P_i, N_i) == (0.0, float("inf"))


def test_rest_before_walks_back_to_the_first_frame_that_moved():
    """A box turning onto its side (40°, 25°, 12° before the landing about the landing edge), then 4 frames at rest;
    the last is the settled frame: the frames at rest before it are found, not the turning ones. A frame slid
    15 mm along the box's long axis (its surface fits, ``still_fit``) is told by its keypoints (each printed point a
    fixed ORB descriptor) and ends the walk; a frame without points ends it too."""
    from service.tracking.resettle import still_fit
    from service.tracking.tracker import FrameObs, _rest_before
    from service.tracking.types import TrackingConfig

    rng = np.random.default_rng(6)
    X_t = settled_truth(make_X(np.eye(3), np.array([0.5, 0.0, SIZE[2] / 2])), 0.0)
    pivot = X_t[:3, 3] + np.array([0.0, -SIZE[0] / 2, -SIZE[1] / 2])
    Q, N = box_faces(step=0.003)
    kp = rng.choice(len(Q), 150, replace=False)  # printed points on the box, in O, with their descriptors
    desc = rng.integers(0, 256, (150, 32), dtype=np.uint8)

    def before(deg: float) -> np.ndarray:  # the pose deg before the landing, turned back about the landing edge
        R = so3_exp(np.array([1.0, 0.0, 0.0]) * np.radians(deg))
        return make_X(R @ X_t[:3, :3], pivot + R @ (X_t[:3, 3] - pivot))

    def frame(X: np.ndarray) -> "FrameObs":
        P, Nw = _seen_points(X, rng)
        up = (N[kp] @ X[:3, :3].T)
        vis = (up[:, 2] > 0.5) | (up[:, 0] > 0.5)
        K = Q[kp][vis] @ X[:3, :3].T + X[:3, 3] + rng.normal(0.0, 0.001, (vis.sum(), 3))
        return FrameObs(P, Nw, K, desc[vis], len(P))

    slid = X_t.copy()
    slid[:3, 3] += 0.015 * X_t[:3, 2]
    def frames(rest):
        return [j for j, _ in rest]

    cfg = TrackingConfig(resettle_flush_rest_tol=0.002)
    Rz = so3_exp(np.array([0.0, 0.0, np.radians(1.0)]))  # turned 1° about the vertical through the box, slid 3.6 mm
    nudged = make_X(Rz, X_t[:3, 3] - Rz @ X_t[:3, 3] + np.array([0.003, 0.002, 0.0])) @ X_t
    obs = [frame(X) for X in (before(40.0), before(25.0), before(12.0), nudged, X_t, X_t, X_t)]
    rest = _rest_before(obs, 6, 0, cfg)
    assert frames(rest) == [3, 4, 5]
    d_t, d_r = pose_distance(rest[0][1] @ X_t, nudged)  # the nudge (1°, 3.6 mm) measured by the keypoints
    assert d_r < 0.3 and d_t < 0.001
    assert pose_distance(rest[1][1] @ X_t, X_t)[0] < 0.001
    assert pose_distance(X_t, nudged)[0] > 0.003
    assert frames(_rest_before(obs, 6, 4, cfg)) == [5]
    obs[4] = frame(slid)
    frac, d = still_fit(obs[4].P_W, obs[6].P_W, obs[6].N_W)
    assert frac >= 0.9 and d <= 0.002  # the surface alone would call it at rest
    assert frames(_rest_before(obs, 6, 0, cfg)) == [5]
    obs[4] = FrameObs(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), None, 0)
    assert frames(_rest_before(obs, 6, 0, cfg)) == [5]


def test_flush_rest_validated():
    import pytest

    from service.tracking import TrackingConfig

    with pytest.raises(ValueError, match="resettle_flush_rest_tol"):
        TrackingConfig(resettle_flush_rest_tol=-0.001)
    with pytest.raises(ValueError, match="resettle_flush_rest_tol"):
        TrackingConfig(resettle_flush_rest_frac=0.0)
    with pytest.raises(ValueError, match="resettle_flush_rest_tol"):
        TrackingConfig(resettle_flush_rest_matches=2.5)
    assert TrackingConfig().resettle_flush_rest_tol == 0.002


def test_tip_path_about_the_leading_edge_and_its_best_fitting_pose():
    """The path of a carton tipped 90° about its bottom edge at +y, landed 1 cm beyond the pure turn: its ends, its
    half-way pose (45° about the edge, half the slide), the leading edge found from the base; the path pose that
    150 noisy points of the box at 30° of the turn fit best (``path_keys``) is found within 1°; a pose on the path is
    0 from it, one turned 20° off the path (about the vertical of the body) is far (``path_offset``)."""
    from scipy.spatial import cKDTree

    from service.tracking.resettle import leading_pivot, path_keys, path_offset, tip_path

    table = 0.0
    X_r = make_X(np.eye(3), np.array([0.4, 0.1, table + SIZE[2] / 2]))
    slid = settled_truth(X_r, table)
    slid[1, 3] += 0.01
    Q, Nq = box_faces()
    B = base_points(Q, X_r, table, inset=0.0)
    pivot = leading_pivot(B @ X_r[:3, :3].T + X_r[:3, 3], np.array([0.0, 1.0, 0.0]), table)
    assert np.allclose(pivot, [0.4, 0.1 + SIZE[1] / 2, table], atol=0.004)
    path = tip_path(X_r, slid, pivot)
    assert pose_distance(path(0.0), X_r)[0] < 1e-9 and pose_distance(path(1.0), slid)[0] < 1e-9
    R = so3_exp(np.array([-1.0, 0.0, 0.0]) * np.pi / 4)
    mid = make_X(R, pivot + R @ (X_r[:3, 3] - pivot) + np.array([0.0, 0.005, 0.0]))
    assert pose_distance(path(0.5), mid)[0] < 0.003 and pose_distance(path(0.5), mid)[1] < 0.5
    poses = [path(k / 90) for k in range(91)]
    rng = np.random.default_rng(5)
    sel = rng.choice(len(Q), 150, replace=False)
    P_W = Q[sel] @ poses[30][:3, :3].T + poses[30][:3, 3] + rng.normal(0, 0.001, (150, 3))
    keys = path_keys(P_W, poses, cKDTree(Q), 0.008)
    assert abs(max(range(len(poses)), key=lambda k: keys[k]) - 30) <= 1
    assert path_offset(poses[40], poses, 500.0) == 0.0
    off = poses[30] @ make_X(so3_exp(np.array([0.0, 0.0, np.radians(20.0)])), np.zeros(3))
    assert path_offset(off, poses, 500.0) > 15.0


def test_fall_frame_fits_decided_by_the_tipping_path():
    """Among registrations of a fall frame that fit equally (a face turning within its own plane), the one on the
    tipping path wins (``tracker._on_path``); one that fits better by more than ``resettle_tip_tol`` wins even off
    the path; ``resettle_tip_tol`` 0 is off and the setting is validated."""
    import pytest

    from service.tracking.geometry import IcpResult
    from service.tracking.resettle import tip_path
    from service.tracking.tracker import _on_path
    from service.tracking.types import TrackingConfig

    X_r = make_X(np.eye(3), np.array([0.4, 0.1, SIZE[2] / 2]))
    path = tip_path(X_r, settled_truth(X_r, 0.0), np.array([0.4, 0.1 + SIZE[1] / 2, 0.0]))
    poses = [path(k / 90) for k in range(91)]
    on = poses[50]
    off = poses[50] @ make_X(so3_exp(np.array([0.0, 0.0, np.radians(12.0)])), np.zeros(3))

    def fit(X: np.ndarray, frac: float, rmse: float) -> IcpResult:
        return IcpResult(X, frac, rmse, 100, np.zeros(100))

    cfg = TrackingConfig()
    assert cfg.resettle_tip_tol > 0
    best = _on_path([fit(off, 1.0, 0.00100), fit(on, 1.0, 0.00105)], poses, cfg)  # off fits by 0.001 better
    assert best.X_WO is on
    best = _on_path([fit(off, 1.0, 0.0010), fit(on, 0.9, 0.0012)], poses, cfg)  # off better by 0.104
    assert best.X_WO is off
    with pytest.raises(ValueError, match="resettle_tip_tol"):
        TrackingConfig(resettle_tip_tol=-0.01)
    with pytest.raises(ValueError, match="resettle_tip_m_deg"):
        TrackingConfig(resettle_tip_m_deg=float("inf"))


def test_box_tipping_away_from_the_camera_lands_on_its_unseen_face():
    """A box that tips away from the camera: the pre-fall model holds its top and the faces the camera sees (−y, the
    trailing face, and +x), never the +y face that leads. Without the box's sides the join has no leading face (it is
    not adopted); with them (``box_base_O``: the base it stood on) the leading face is the +y side (at right angles
    to the seen sides, nearest the tipping direction, at the model's extent along it) and the join is the truth."""
    from service.tracking.resettle import box_face

    table = 0.0
    X_r = make_X(so3_exp(np.array([0.0, 0.0, np.radians(25.0)])), np.array([0.4, 0.1, table + SIZE[2] / 2]))
    Q, Nq = box_faces(z_min=-0.01)
    vis = (Nq @ np.array([0.6, -1.0, 0.4])) > 0  # top, −y and +x: the +y face is hidden
    Q, Nq = Q[vis], Nq[vis]
    Q = Q + np.random.default_rng(4).normal(0, 0.0008, Q.shape)
    Rz = X_r[:3, :3]
    # the truth: the standing box turned 90° about its bottom edge at +y of its own frame
    e = Rz @ np.array([-1.0, 0.0, 0.0])
    pivot = X_r[:3, 3] + Rz @ np.array([0.0, SIZE[1] / 2, -SIZE[2] / 2])
    Rt = so3_exp(e * np.pi / 2)
    truth = make_X(Rt @ Rz, pivot + Rt @ (X_r[:3, 3] - pivot))
    h = so3_exp(np.array([0, 0, np.radians(7.0)])) @ e  # the loop's tip axis, 7° off
    X0, face0 = landing_pose(X_r, h, Q, Nq, table)
    assert not face0  # no leading face seen: the join is not adopted
    base_O = np.array([0.0, 0.0, -1.0])
    X1, face1 = landing_pose(X_r, h, Q, Nq, table, box_base_O=base_O)
    assert face1
    dt, da = pose_distance(X1, truth)
    assert da < 0.5 and dt < 0.003, (da, dt)
    # the side directions come from the seen faces, not from the tip axis: the same leading face 30° off
    h30 = so3_exp(np.array([0, 0, np.radians(30.0)])) @ e
    assert pose_distance(landing_pose(X_r, h30, Q, Nq, table, box_base_O=base_O)[0], truth)[1] < 0.5
    # a seen face the leading one is in the model: box_base_O changes nothing
    Qa, Na = box_faces(z_min=-0.01)
    va = (Na @ np.array([0.0, 1.0, 0.3])) > 0
    Xa, fa = landing_pose(X_r, h, Qa[va], Na[va], table)
    Xb, fb = landing_pose(X_r, h, Qa[va], Na[va], table, box_base_O=base_O)
    assert fa and fb and np.array_equal(Xa, Xb)
    # box_face itself: the +y side of the box in W at X_r
    n, off = box_face(Q @ Rz.T + X_r[:3, 3], Nq @ Rz.T, np.cross(h, [0.0, 0.0, 1.0]), Rz @ base_O)
    assert n @ (Rz @ np.array([0.0, 1.0, 0.0])) > 0.9999


def test_box_face_refuses_curved_and_oblique_sides():
    """No box: an egg's and a bottle's sides are curved (no flat side), and a triangular prism's seen sides meet at
    60°, not at right angles."""
    from service.tracking.resettle import box_face

    b = np.array([0.0, 0.0, -1.0])
    f = np.array([0.0, 1.0, 0.0])
    rng = np.random.default_rng(5)
    u = rng.normal(size=(6000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    ax = np.array([0.03, 0.03, 0.045])  # egg-like, standing
    N = u * ax / ax**2
    assert box_face(u * ax, N / np.linalg.norm(N, axis=1, keepdims=True), f, b) is None
    th, z = rng.uniform(-np.pi, np.pi, 8000), rng.uniform(-0.05, 0.09, 8000)  # a bottle's side, radius 3.5 cm
    N = np.column_stack([np.cos(th), np.sin(th), np.zeros_like(th)])
    assert box_face(0.035 * N + np.outer(z, [0.0, 0.0, 1.0]), N, f, b) is None
    # a triangular prism (side 8 cm), two of its three sides seen
    Ps, Ns = [], []
    for k in range(2):
        a = np.radians(-90.0 + 120.0 * k)
        n = np.array([np.cos(a), np.sin(a), 0.0])
        t = np.cross([0.0, 0.0, 1.0], n)
        s, zz = np.meshgrid(np.linspace(-0.04, 0.04, 30), np.linspace(-0.05, 0.09, 30))
        Ps.append(0.023 * n + s.reshape(-1, 1) * t + zz.reshape(-1, 1) * [0.0, 0.0, 1.0])
        Ns.append(np.tile(n, (s.size, 1)))
    assert box_face(np.concatenate(Ps), np.concatenate(Ns), f, b) is None
    # the same two sides at right angles: a box
    Ps[1] = Ps[1] @ so3_exp(np.array([0.0, 0.0, np.radians(-30.0)])).T
    Ns[1] = Ns[1] @ so3_exp(np.array([0.0, 0.0, np.radians(-30.0)])).T
    assert box_face(np.concatenate(Ps), np.concatenate(Ns), f, b) is not None


def _tipping_away():
    """The box resting at 25° yaw on a table at 2 cm, about to tip about its +y bottom edge, away from a camera that
    sees its top, −y and +x faces (the leading +y face hidden): (table, X_r, Q, Nq, Rz, Rt, truth, h) — the rest pose,
    the seen model points and normals in O, the rest rotation, the quarter turn, the landed pose and a tip axis 7° off
    the true one."""
    table = 0.02
    X_r = make_X(so3_exp(np.array([0.0, 0.0, np.radians(25.0)])), np.array([0.4, 0.1, table + SIZE[2] / 2]))
    Q, Nq = box_faces(z_min=-0.01)
    vis = (Nq @ np.array([0.6, -1.0, 0.4])) > 0  # top, −y and +x: the +y face that leads is hidden
    Q, Nq = Q[vis], Nq[vis]
    Rz = X_r[:3, :3]
    e = Rz @ np.array([-1.0, 0.0, 0.0])
    pivot = X_r[:3, 3] + Rz @ np.array([0.0, SIZE[1] / 2, -SIZE[2] / 2])
    Rt = so3_exp(e * np.pi / 2)
    truth = make_X(Rt @ Rz, pivot + Rt @ (X_r[:3, 3] - pivot))
    h = so3_exp(np.array([0, 0, np.radians(7.0)])) @ e
    return table, X_r, Q, Nq, Rz, Rt, truth, h


def test_box_face_join_needs_the_body_resting_on_the_table():
    """A landing is a body coming to rest on the table. The box that tips away from the camera (its leading face never
    seen) is joined on the face taken from its sides when, at the settled frame, the tracker's model under the tracked
    pose rests on the table (here the truth, or the truth pushed 5 mm into the table); the same box held 3 cm above
    the table (carried by a gripper and turned) is not joined. A model with its leading face seen is joined as before,
    held or not (the gate is the box-face path's only)."""
    from service.tracking import TrackingConfig
    from service.tracking.resettle import box_landing_pose, on_table

    table, X_r, Q, Nq, Rz, Rt, truth, h = _tipping_away()
    assert TrackingConfig().resettle_box_face and TrackingConfig().resettle_box_rest == 0.015  # on by default
    base_O, rest = np.array([0.0, 0.0, -1.0]), TrackingConfig().resettle_box_rest
    up = np.eye(4)
    up[2, 3] = 0.03
    down = np.eye(4)
    down[2, 3] = -0.005
    assert on_table(truth, Q, table, rest) and on_table(down @ truth, Q, table, rest)
    assert not on_table(up @ truth, Q, table, rest)
    X1, f1 = box_landing_pose(X_r, h, Q, Nq, table, base_O, truth, Q, rest)  # resting: joined on the unseen face
    assert f1 and pose_distance(X1, truth)[1] < 0.5
    assert box_landing_pose(X_r, h, Q, Nq, table, base_O, down @ truth, Q, rest)[1]
    X2, f2 = box_landing_pose(X_r, h, Q, Nq, table, base_O, up @ truth, Q, rest)  # held 3 cm up: no join
    assert not f2 and np.array_equal(X2, landing_pose(X_r, h, Q, Nq, table)[0])
    # the leading face seen: the gate does not apply
    Qa, Na = box_faces(z_min=-0.01)
    va = (Na @ np.array([0.0, 1.0, 0.3])) > 0
    Xa, fa = landing_pose(X_r, h, Qa[va], Na[va], table)
    Xb, fb = box_landing_pose(X_r, h, Qa[va], Na[va], table, base_O, up @ truth, Qa[va], rest)
    assert fa and fb and np.array_equal(Xa, Xb)


def test_box_face_join_moved_by_the_drop_of_the_face_on_top():
    """The box that tips away from the camera, its model lacking the strip of 1 cm next to the leading face (the seen
    sides end short of it): the face taken from the sides lies 1 cm short, so the join turns about an edge 1 cm short
    and leaves the box 1 cm short along the tipping direction and 1 cm low. The settled frame sees the face on top
    (the trailing face, −y, which the pre-fall model holds) 1 cm higher than the join puts it: with ``top``
    (``resettle_box_drop``) the join is moved by that drop along the tipping direction and up, onto the truth; a drop
    of the wrong sign (the frame's face lower) or a frame without a face on top changes nothing."""
    from service.tracking.resettle import box_landing_pose, top_face_drop
    from service.tracking.types import TrackingConfig

    table, X_r, Q, Nq, Rz, Rt, truth, h = _tipping_away()
    short = Q[:, 1] < SIZE[1] / 2 - 0.01  # the model lacks the strip next to the leading face
    Q, Nq = Q[short], Nq[short]
    base_O, rest = np.array([0.0, 0.0, -1.0]), 0.015
    # the settled frame: the whole face on top (−y of the box) and the +x side, in W at the truth
    Qt, Nt = box_faces()
    seen = (Nt @ np.array([0.0, -1.0, 0.0]) > 0.9) | (Nt @ np.array([1.0, 0.0, 0.0]) > 0.9)
    rng = np.random.default_rng(6)
    P_W = Qt[seen] @ truth[:3, :3].T + truth[:3, 3] + rng.normal(0, 0.0005, (seen.sum(), 3))
    N_W = Nt[seen] @ truth[:3, :3].T
    X0, f0 = box_landing_pose(X_r, h, Q, Nq, table, base_O, truth, Q, rest)  # without the drop: 1 cm short and low
    dt0 = truth[:3, 3] - X0[:3, 3]
    f = Rt @ Rz @ np.array([0.0, 0.0, 1.0])  # the tipping direction: the box's top end now points along it
    assert f0 and 0.008 < dt0 @ f < 0.012 and 0.008 < dt0[2] < 0.012, dt0
    X1, f1 = box_landing_pose(X_r, h, Q, Nq, table, base_O, truth, Q, rest, top=(P_W, N_W, 0.03))
    dt, da = pose_distance(X1, truth)
    assert f1 and dt < 0.002 and da < 0.5, (dt, da)
    assert np.array_equal(X1[:3, :3], X0[:3, :3])  # a shift only
    # a frame whose face on top is lower than the join's (no drop) or that shows none: unchanged
    low = P_W - np.array([0.0, 0.0, 0.015])
    assert np.array_equal(top_face_drop(X0, X_r, Q, Nq, low, N_W, table, 0.03), X0)
    side = N_W[:, 2] < 0.5
    assert np.array_equal(top_face_drop(X0, X_r, Q, Nq, P_W[side], N_W[side], table, 0.03), X0)
    # a drop beyond max_shift is left out; the option is off by default and validated
    assert np.array_equal(top_face_drop(X0, X_r, Q, Nq, P_W, N_W, table, 0.005), X0)
    assert not TrackingConfig().resettle_box_drop
    import pytest

    with pytest.raises(ValueError, match="resettle_box_drop"):
        TrackingConfig(resettle_box_drop=1)


def test_box_lying_on_its_unseen_side_laid_flat():
    """The box that tipped away from the camera lies on its +y side, which no view saw. A pose rolled 2° about its
    long axis (the tipping direction) and tilted 1.5° about the tip axis: making the base vertical (``side_pose``)
    removes only the tilt; laying the side found from the box's seen sides (``box_rest_face``) flat (``down_pose``)
    removes both, and keeps the yaw. A model with no box (a bottle's side) gives no face."""
    from service.tracking.resettle import box_rest_face, down_pose, side_pose

    table = 0.0
    Q, Nq = box_faces(z_min=-0.01)
    vis = (Nq @ np.array([0.6, -1.0, 0.4])) > 0  # top, −y and +x: the +y face is hidden
    Q, Nq = Q[vis], Nq[vis]
    X_r = make_X(np.eye(3), np.array([0.4, 0.1, table + SIZE[2] / 2]))
    truth = settled_truth(X_r, table)  # on the +y side, its long axis (z of O) along the tipping direction
    base_O = np.array([0.0, 0.0, -1.0])
    down_O = truth[:3, :3].T @ np.array([0.0, 0.0, -1.0])
    n = box_rest_face(Q, Nq, base_O, down_O)
    assert n is not None and n @ np.array([0.0, 1.0, 0.0]) > 0.9999
    f = truth[:3, :3] @ np.array([0.0, 0.0, 1.0])
    hax = np.cross([0.0, 0.0, 1.0], f)
    off = make_X(so3_exp(f * np.radians(2.0)) @ so3_exp(hax * np.radians(1.5)), np.zeros(3))
    bad = off @ truth
    Xs, _ = side_pose(bad, Q, base_O)
    assert pose_distance(Xs, truth)[1] > 1.5  # the roll about the long axis is left
    Xd, tilt = down_pose(bad, Q, n)
    assert 2.0 < tilt < 3.0 and pose_distance(Xd, truth)[1] < 0.05
    th, z = np.random.default_rng(7).uniform(-np.pi, np.pi, 4000), np.random.default_rng(8).uniform(-0.05, 0.09, 4000)
    Nb = np.column_stack([np.cos(th), np.sin(th), np.zeros_like(th)])
    assert box_rest_face(0.035 * Nb + np.outer(z, [0.0, 0.0, 1.0]), Nb, base_O, np.array([0.0, 1.0, 0.0])) is None
