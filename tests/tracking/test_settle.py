"""Fast-motion gaps (service.tracking.settle): detection of a fall that ends still, resting poses on the faces of a
model's hull, and the horizontal slide search."""

import numpy as np
from scipy.spatial import cKDTree

from service.tracking.settle import find_gap, resting_pose, resting_rotations, slide_search
from service.transforms import make_X, rotation_angle, so3_exp


def _box_points(size, n=4000, seed=0):
    """Points (n,3) on the surface of an axis-aligned box of edge lengths ``size``, centred at the origin."""
    rng = np.random.default_rng(seed)
    a = np.asarray(size, float) / 2
    P = rng.uniform(-a, a, (n, 3))
    ax = rng.integers(0, 3, n)
    P[np.arange(n), ax] = np.where(rng.random(n) < 0.5, -a[ax], a[ax])
    return P


def _sequence(steps_deg):
    """Poses (N,4,4) turning about x by the given per-frame steps (first pose identity)."""
    X = [np.eye(4)]
    for s in steps_deg:
        X.append(X[-1] @ make_X(so3_exp(np.radians(s) * np.array([1.0, 0, 0])), np.zeros(3)))
    return np.stack(X)


def test_find_gap_marks_the_fall_that_ends_still():
    steps = [0.2] * 10 + [1.0, 3.0, 5.0, 8.0, 11.0, 14.0, 15.0] + [0.1] * 5  # frames 1..22
    X = _sequence(steps)
    tr = np.ones(len(X), bool)
    kw = dict(still_frames=3, still_deg=1.0, still_dist=0.003, fast_deg=8.0, fall_deg=2.0, window=8)
    first_fall = 1 + steps.index(3.0)  # frame reached by the first step above fall_deg
    # inside the fall or before the still run is complete: nothing
    assert find_gap(X, tr, first_fall + 3, **kw) is None
    assert find_gap(X, tr, len(steps) - 4, **kw) is None  # frames 16-18: the step onto 17 is the landing's
    assert find_gap(X, tr, len(steps) - 3, **kw) is not None  # frames 17-19: landed, then two still steps
    g0 = find_gap(X, tr, len(steps), **kw)
    assert g0 is not None and first_fall - 1 <= g0 <= first_fall
    # a gap handled before (ending at or after the fast steps) is not found again
    assert find_gap(X, tr, len(steps), **kw, after=len(steps) - 4) is None
    # lost frames at the landing: the step over the gap counts per frame
    tr2 = tr.copy()
    tr2[first_fall + 4: first_fall + 6] = False
    assert find_gap(X, tr2, len(steps), **kw) is not None


def test_find_gap_ignores_slow_motion():
    X = _sequence([0.2] * 5 + [1.5] * 20 + [0.1] * 5)
    tr = np.ones(len(X), bool)
    assert find_gap(X, tr, len(X) - 1, still_frames=3, still_deg=1.0, still_dist=0.003, fast_deg=8.0,
                    fall_deg=2.0, window=8) is None


def test_resting_rotations_contain_the_lying_box():
    Q = _box_points((0.07, 0.07, 0.185))
    R_true = so3_exp(np.radians(37.0) * np.array([0, 0, 1.0])) @ so3_exp(np.radians(90.0) * np.array([1.0, 0, 0]))
    Rs = resting_rotations(Q, yaw_deg=15.0)
    assert 6 * 24 >= len(Rs) >= 4 * 24  # the six faces of the box (the small ones may merge with none)
    best = min(np.degrees(rotation_angle(R.T @ R_true)) for R in Rs)
    assert best <= 8.0  # half the yaw step, and the face normal exact
    P_W = (Q @ R_true.T)[:100] + np.array([0.5, -0.1, 0.2])
    X = resting_pose(R_true, Q, P_W, table_height=0.02)
    h = Q @ X[2, :3] + X[2, 3]
    assert abs(h.min() - 0.02) < 1e-9
    assert np.linalg.norm(X[:2, 3] + (Q @ R_true.T)[:, :2].mean(0) - P_W[:, :2].mean(0)) < 1e-9


def test_slide_search_recovers_a_horizontal_offset():
    Q = _box_points((0.07, 0.185, 0.07), n=3000, seed=1)
    tree = cKDTree(Q)
    X_true = make_X(np.eye(3), np.array([0.6, -0.1, 0.035]))
    # the frame sees the top and the two faces towards -x and -y (a corner view)
    vis = (Q[:, 2] > 0.034) | (Q[:, 0] < -0.034) | (Q[:, 1] < -0.092)
    P_W = Q[vis][::3] + X_true[:3, 3]
    X0 = X_true.copy()
    X0[:2, 3] += (0.05, -0.07)
    X, _ = slide_search(P_W, X0, tree, Q[::3], None)
    assert np.linalg.norm(X[:3, 3] - X_true[:3, 3]) < 0.004
    assert np.allclose(X[:3, :3], X0[:3, :3])
