"""A settled box's position along its tip axis from the ends of its mask (service.tracking.resettle: axis_extent,
end_seen, axis_shift, moved_along; tracker._resettle_axis)."""

import numpy as np

from service.tracking.resettle import axis_extent, axis_shift, end_seen, moved_along, table_end
from service.transforms import make_X, so3_exp

from tests.tracking.test_resettle import SIZE, box_faces, settled_truth


def _seen(X_WO: np.ndarray, cam: np.ndarray) -> np.ndarray:
    """The box's surface points in W that face the camera at ``cam`` (3,) with pose X_WO."""
    P, N = box_faces(step=0.002)
    P_W, N_W = P @ X_WO[:3, :3].T + X_WO[:3, 3], N @ X_WO[:3, :3].T
    return P_W[np.einsum("ij,ij->i", N_W, cam - P_W) > 0]


def _extents(poses_true: list, poses_tracked: list, h_O: np.ndarray, cam: np.ndarray, cut: float | None = None
             ) -> np.ndarray:
    out = []
    for Xt, Xk in zip(poses_true, poses_tracked):
        P_W = _seen(Xt, cam)
        if cut is not None:  # an end hidden: the points beyond `cut` along h (in the true body frame) not seen
            P_W = P_W[(P_W - Xt[:3, 3]) @ (Xt[:3, :3] @ h_O) < cut]
        out.append(axis_extent(P_W, Xk, h_O))
    return np.array(out)


def _scene():
    X_r = make_X(so3_exp(np.array([0.0, 0.0, 0.4])), np.array([0.45, 0.05, 0.0925 + 0.02]))
    X_s = settled_truth(X_r, 0.02)
    h_O = np.array([1.0, 0.0, 0.0])  # the tip axis (settled_truth turns about the box's x axis)
    cam = np.array([0.4, -0.6, 0.6])
    rng = np.random.default_rng(3)
    ref_true = [make_X(X_r[:3, :3], X_r[:3, 3] + rng.normal(0, 3e-4, 3)) for _ in range(8)]
    post_true = [X_s] * 20
    return X_r, X_s, h_O, cam, ref_true, post_true


def test_settled_box_moved_along_its_axis_onto_the_ends_seen_before_the_fall():
    X_r, X_s, h_O, cam, ref_true, post_true = _scene()
    ref = _extents(ref_true, ref_true, h_O, cam)
    for off in (0.006, -0.009):  # the tracked settled pose off along the axis (the landing's sideways slide)
        X_k = moved_along(X_s, h_O, off)
        post = _extents(post_true, [X_k] * 20, h_O, cam)
        shift = axis_shift(ref, post)
        assert shift is not None and abs(shift + off) < 5e-4
        X_fixed = moved_along(X_k, h_O, shift)
        assert np.linalg.norm(X_fixed[:3, 3] - X_s[:3, 3]) < 5e-4
        assert np.allclose(X_fixed[:3, :3], X_s[:3, :3])


def test_axis_shift_refused_when_an_end_is_not_seen_or_the_frames_disagree():
    X_r, X_s, h_O, cam, ref_true, post_true = _scene()
    ref = _extents(ref_true, ref_true, h_O, cam)
    X_k = moved_along(X_s, h_O, 0.006)
    cut = _extents(post_true, [X_k] * 20, h_O, cam, cut=0.02)  # one end hidden in every settled frame: 15 mm short
    assert axis_shift(ref, cut) is None
    post = _extents(post_true, [X_k] * 20, h_O, cam)
    spread = post + np.linspace(-0.006, 0.006, len(post))[:, None]  # the frames' shifts spread by 12 mm
    assert axis_shift(ref, spread) is None
    few = post.copy()
    few[:12] = np.nan  # both ends seen in 8 of 20 settled frames
    assert axis_shift(ref, few) is None
    assert axis_shift(ref[:2], post) is None  # 2 reference frames
    small = _extents(post_true, [moved_along(X_s, h_O, 0.001)] * 20, h_O, cam)
    assert axis_shift(ref, small) is None  # 1 mm: within the measurement's own bias


def _view(occluder: tuple[int, int] | None = None, over_end: int | None = None):
    """A camera 1 m above the table (z = 0) looking down; the top of a box 6 cm high over x in [-5, 5] cm,
    y in [-3, 3] cm; an occluder 30 cm above the table over image columns ``occluder``; ``over_end``: the box's
    pixels from that column on hidden by the occluder too (not in the mask)."""
    K = np.array([[500.0, 0.0, 80.0], [0.0, 500.0, 60.0], [0.0, 0.0, 1.0]])
    X_WC = make_X(np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 1.0]))
    H, W = 120, 160
    v, u = np.mgrid[0:H, 0:W]
    depth = np.ones((H, W))
    x, y = (u - 80) / 500 * 0.94, -(v - 60) / 500 * 0.94
    box = (np.abs(x) <= 0.05) & (np.abs(y) <= 0.03)
    depth[box] = 0.94
    mask = box.copy()
    if occluder is not None:
        cols = (u >= occluder[0]) & (u < occluder[1])
        depth[cols] = 0.7
        mask &= ~cols
    if over_end is not None:
        cols = u >= over_end
        depth[cols & (np.abs(y) <= 0.05)] = 0.7
        mask &= ~cols
    vv, uu = np.nonzero(mask)
    z = depth[vv, uu]
    P_C = np.stack([(uu - 80) / 500 * z, (vv - 60) / 500 * z, z], 1)
    P_W = P_C @ X_WC[:3, :3].T + X_WC[:3, 3]
    return P_W, depth, mask, K, X_WC


def test_an_end_is_seen_unless_something_in_front_cuts_it():
    h = np.array([1.0, 0.0, 0.0])
    P_W, depth, mask, K, X_WC = _view()
    assert end_seen(P_W, h, depth, mask, K, X_WC, 0.0) and end_seen(P_W, -h, depth, mask, K, X_WC, 0.0)
    P_W, depth, mask, K, X_WC = _view(occluder=(108, 125))  # beyond the +x end, 1-18 px from it
    assert not end_seen(P_W, h, depth, mask, K, X_WC, 0.0)
    assert end_seen(P_W, -h, depth, mask, K, X_WC, 0.0)
    P_W, depth, mask, K, X_WC = _view(over_end=95)  # the +x part of the box hidden: the mask ends at the occluder
    assert P_W[:, 0].max() < 0.03
    assert not end_seen(P_W, h, depth, mask, K, X_WC, 0.0)
    assert end_seen(P_W, -h, depth, mask, K, X_WC, 0.0)


def _slide_extents(poses_true: list, poses_tracked: list, u_O: np.ndarray, cam: np.ndarray, table: float,
                   standing: bool, lost: float = 0.0, cut: float | None = None) -> np.ndarray:
    """Extents along the box's up axis u: standing, the top from the seen points and the base from the table
    (``table_end``; the lower part hidden below 3 cm from the bottom); lying, both ends from the seen points, each
    end's outermost ``lost`` (m) of outline lost, and with ``cut`` the points below ``cut`` along u not seen (the base
    end hidden)."""
    out = []
    for Xt, Xk in zip(poses_true, poses_tracked):
        P_W = _seen(Xt, cam)
        s = (P_W - Xt[:3, 3]) @ (Xt[:3, :3] @ u_O)
        half = SIZE[2] / 2
        if standing:
            P_W = P_W[s > -half + 0.03]
        else:
            P_W = P_W[(s > -half + lost) & (s < half - lost)]
            if cut is not None:
                P_W = P_W[(P_W - Xt[:3, 3]) @ (Xt[:3, :3] @ u_O) > cut]
        lo, hi = axis_extent(P_W, Xk, u_O)
        out.append((table_end(Xk, u_O, table) if standing else lo, hi))
    return np.array(out)


def test_table_end_is_the_base_of_a_standing_box_and_nan_for_a_lying_one():
    X_r, X_s, h_O, cam, ref_true, post_true = _scene()
    u_O = np.array([0.0, 0.0, 1.0])
    assert abs(table_end(X_r, u_O, 0.02) + SIZE[2] / 2) < 1e-9  # the base, half the height below the centre
    tilted = make_X(so3_exp(np.array([np.radians(10.0), 0.0, 0.0])) @ X_r[:3, :3], X_r[:3, 3])
    assert abs(table_end(tilted, u_O, 0.02) + SIZE[2] / 2 / np.cos(np.radians(10.0))) < 1e-9
    assert np.isnan(table_end(X_s, u_O, 0.02))  # lying: u is horizontal


def test_settled_box_moved_along_the_tipping_direction_onto_its_standing_ends():
    X_r, X_s, h_O, cam, ref_true, post_true = _scene()
    u_O = np.array([0.0, 0.0, 1.0])  # the box's up axis: along the tipping direction once it lies
    f_W = X_s[:3, :3] @ u_O
    assert abs(f_W[2]) < 1e-9  # lying along the table
    ref = _slide_extents(ref_true, ref_true, u_O, cam, 0.02, standing=True)
    assert np.allclose(ref[:, 1] - ref[:, 0], SIZE[2], atol=2e-3)  # the standing height, table to top
    for off in (-0.0087, 0.005):  # the tracked settled pose short (the landing's slide) or beyond it along f
        X_k = moved_along(X_s, u_O, off)
        post = _slide_extents(post_true, [X_k] * 20, u_O, cam, 0.02, standing=False, lost=0.004)
        assert axis_shift(ref, post) is None  # 8 mm short: refused by the tip axis' symmetric 6 mm length test
        shift = axis_shift(ref, post, len_short=0.02, min_frac=0.3)
        assert shift is not None and abs(shift + off) < 1e-3
        X_fixed = moved_along(X_k, u_O, shift)
        assert np.linalg.norm(X_fixed[:3, 3] - X_s[:3, 3]) < 1e-3
        assert np.allclose(X_fixed[:3, :3], X_s[:3, :3])


def test_slide_refused_when_the_base_end_is_hidden_or_too_few_frames_see_both_ends():
    X_r, X_s, h_O, cam, ref_true, post_true = _scene()
    u_O = np.array([0.0, 0.0, 1.0])
    ref = _slide_extents(ref_true, ref_true, u_O, cam, 0.02, standing=True)
    X_k = moved_along(X_s, u_O, -0.0087)
    hidden = _slide_extents(post_true, [X_k] * 20, u_O, cam, 0.02, standing=False, lost=0.004, cut=-0.06)
    assert axis_shift(ref, hidden, len_short=0.02, min_frac=0.3) is None  # 30 mm of the base end hidden
    post = _slide_extents(post_true, [X_k] * 20, u_O, cam, 0.02, standing=False, lost=0.004)
    few = post.copy()
    few[:15] = np.nan  # both ends seen in 5 of 20 settled frames
    assert axis_shift(ref, few, len_short=0.02, min_frac=0.3) is None
    assert axis_shift(ref, few, len_short=0.02, min_frac=0.25) is not None
