"""A lying body of revolution's position along its axis from the ends of its mask (service.tracking.lying:
lying_runs, axis_end_offsets, axis_end_shift; resettle.axis_extent, moved_along)."""

import numpy as np

from service.tracking.lying import axis_end_offsets, axis_end_shift, lying_runs
from service.tracking.resettle import axis_extent, moved_along
from service.transforms import make_X, so3_exp

R, H = 0.035, 0.20  # a cylinder standing on its base at frame 0: O at its centre, base at z = -H/2


def _cylinder(step: float = 0.003) -> tuple[np.ndarray, np.ndarray]:
    """Surface points (M,3) and outward normals (M,3) in O of the closed cylinder."""
    th = np.arange(0.0, 2 * np.pi, step / R)
    z = np.arange(-H / 2, H / 2 + 1e-9, step)
    T, Z = np.meshgrid(th, z)
    side = np.c_[R * np.cos(T.ravel()), R * np.sin(T.ravel()), Z.ravel()]
    ns = np.c_[np.cos(T.ravel()), np.sin(T.ravel()), np.zeros(T.size)]
    g = np.arange(-R, R + 1e-9, step)
    U, V = np.meshgrid(g, g)
    disc = np.c_[U.ravel(), V.ravel()][(U.ravel() ** 2 + V.ravel() ** 2) <= R**2]
    caps = [np.c_[disc, np.full(len(disc), s * H / 2)] for s in (-1.0, 1.0)]
    nc = [np.tile([0.0, 0.0, s], (len(disc), 1)) for s in (-1.0, 1.0)]
    return np.vstack([side] + caps), np.vstack([ns] + nc)


def _seen(X_WO: np.ndarray, cam: np.ndarray, short: float = 0.0) -> np.ndarray:
    """The points facing the camera at ``cam`` (3,), in W, with the last ``short`` m at each end not seen (the mask's
    shortfall at an end: edge pixels the depth filter drops, the rounded rim)."""
    P, N = _cylinder()
    keep = np.abs(P[:, 2]) <= H / 2 - short + 1e-9
    P, N = P[keep], N[keep]
    P_W, N_W = P @ X_WO[:3, :3].T + X_WO[:3, 3], N @ X_WO[:3, :3].T
    return P_W[np.einsum("ij,ij->i", N_W, cam - P_W) > 0]


def _lying(yaw: float, x: float) -> np.ndarray:
    """A pose of the cylinder lying on the table (z = 0), its axis horizontal along the heading ``yaw``."""
    Rl = so3_exp(np.array([0.0, 0.0, yaw])) @ so3_exp(np.array([0.0, np.pi / 2, 0.0]))
    return make_X(Rl, np.array([x, 0.05, R]))


CAM = np.array([0.2, -0.6, 0.5])
A = np.array([0.0, 0.0, 1.0])  # the axis in O
BASE = -H / 2  # the base plane along a in O (the table at frame 0)


def test_lying_runs_close_short_gaps_and_drop_short_runs():
    lying = np.zeros(40, bool)
    lying[5:12] = True
    lying[14:20] = True  # a gap of 2 frames: the same stretch
    lying[30:33] = True  # 3 frames: too short
    assert lying_runs(lying, min_len=5, gap=3) == [(5, 20)]
    assert lying_runs(lying, min_len=5, gap=1) == [(5, 12), (14, 20)]
    assert lying_runs(np.zeros(5, bool)) == []


def test_a_slid_lying_stretch_is_put_back_by_its_base_end_alone():
    short = 0.005
    top = H / 2  # the standing frames' top (seen from above: no shortfall)
    for off in (0.03, -0.05):  # the tracked poses slid along the axis by `off`
        t = np.arange(60, 200, 2)
        post, truths, tracks = [], [], []
        for k in t:
            X_true = _lying(0.3 + 0.002 * k, 0.45 + 0.0002 * k)
            X_trk = moved_along(X_true, A, off)
            lo, hi = axis_extent(_seen(X_true, CAM, short), X_trk, A)
            post.append((lo, np.nan))  # the top end hidden in every frame (the occluder)
            truths.append(X_true)
            tracks.append(X_trk)
        c = axis_end_offsets(BASE, top, np.array(post), short)
        assert np.isfinite(c).all()
        shift = axis_end_shift(c, t)
        assert shift is not None
        for X_true, X_trk, sh in zip(truths, tracks, shift):
            X_fixed = moved_along(X_trk, A, float(sh))
            assert np.linalg.norm(X_fixed[:3, 3] - X_true[:3, 3]) < 1.5e-3
            assert np.allclose(X_fixed[:3, :3], X_true[:3, :3])


def test_both_ends_seen_the_middle_is_used_and_a_cut_end_is_not_counted():
    short = 0.004
    top = H / 2
    X_true = _lying(0.2, 0.5)
    X_trk = moved_along(X_true, A, 0.02)
    lo, hi = axis_extent(_seen(X_true, CAM, short), X_trk, A)
    c = axis_end_offsets(BASE, top, np.array([[lo, hi]]), short)
    assert abs(c[0] + 0.02) < 2.5e-3  # the middle: moved_along(X_trk, A, c) puts it back
    # the top end cut by 40 mm that the end test passed: the length disagrees, the frame does not count
    P = _seen(X_true, CAM, short)
    P_cut = P[(P - X_true[:3, 3]) @ (X_true[:3, :3] @ A) < H / 2 - 0.04]
    lo2, hi2 = axis_extent(P_cut, X_trk, A)
    assert np.isnan(axis_end_offsets(BASE, top, np.array([[lo2, hi2]]), short)[0])
    # without a known top the base end alone is used
    c3 = axis_end_offsets(BASE, None, np.array([[lo2, hi2]]), short)
    assert abs(c3[0] + 0.02) < 2.5e-3


def test_the_shift_follows_a_slide_that_grows_along_the_stretch():
    t = np.arange(0, 200, 2).astype(float)
    c = -0.065 + 0.00005 * t  # -65 -> -55 mm over the stretch (development 1788)
    shift = axis_end_shift(c, t)
    assert shift is not None and np.max(np.abs(shift - c)) < 1e-3


def test_no_shift_when_few_frames_count_the_ends_disagree_or_it_is_small():
    t = np.arange(0, 100, 2).astype(float)
    rng = np.random.default_rng(1)
    c = np.full(len(t), 0.03) + rng.normal(0, 3e-4, len(t))
    assert axis_end_shift(c, t) is not None
    few = c.copy()
    few[: int(0.6 * len(t))] = np.nan  # an end seen in 40 % of the frames
    assert axis_end_shift(few, t) is None
    noisy = c + rng.choice([-0.01, 0.01], len(t))  # frames 2 cm apart: the ends disagree
    assert axis_end_shift(noisy, t) is None
    assert axis_end_shift(np.full(len(t), 0.004), t) is None  # under the 8 mm floor
    assert np.isnan(axis_end_offsets(None, None, np.array([[0.0, 0.1]]), 0.005)).all()  # no end known
