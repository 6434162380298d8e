"""Strike sessions (the sphere hits the resting box, it slides free): keyframe deferral during a slide, edge points
and normal-compatible ICP pairs (docs/tracking.md, "Strike sessions"). Tiny inputs, no session."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial import cKDTree

import service.tracking.tracker as tracker
from service.tracking import TrackingConfig
from service.tracking.geometry import crease_points, icp
from service.transforms import make_X, so3_exp

DT = 1 / 30


def _X(rotvec_deg=(0.0, 0.0, 0.0), t=(0.0, 0.0, 0.0)):
    return make_X(so3_exp(np.radians(np.asarray(rotvec_deg, float))), np.asarray(t, float))


def test_keyframe_waits_while_the_box_slides_not_while_it_tips():
    cfg = replace(TrackingConfig(), kf_still_speed=0.1)
    A = np.eye(4)
    slide = _X((0, 0, 4.0), (0.012, 0.004, 0.0))  # 0.38 m/s, 120 °/s about the vertical: a strike
    assert tracker._defer_keyframe(A, slide, A, DT, True, False, 0, cfg)
    assert tracker._defer_keyframe(A, slide, A, DT, False, True, 0, cfg)  # new surface waits too (kf_still_new)
    assert not tracker._defer_keyframe(A, slide, A, DT, False, True, 0, replace(cfg, kf_still_new=False))
    assert not tracker._defer_keyframe(A, _X(t=(0.002, 0, 0)), A, DT, True, False, 0, cfg)  # 0.06 m/s: still
    tip = _X((7.0, 0, 0), (0.0, 0.004, 0.002))  # a topple turns about a horizontal axis
    assert not tracker._defer_keyframe(_X((5.0, 0, 0)), tip, A, DT, True, False, 0, cfg)  # 7° from the keyframe
    assert tracker._defer_keyframe(_X((5.0, 0, 0)), tip, A, DT, True, False, 0,
                                   replace(cfg, kf_still_tilt_deg=None))  # any motion (the first rule)
    # at most kf_still_max_frames in a row, and nothing without kf_still_speed
    assert not tracker._defer_keyframe(A, slide, A, DT, True, False, cfg.kf_still_max_frames, cfg)
    assert tracker._defer_keyframe(A, slide, A, DT, True, False, cfg.kf_still_max_frames - 1, cfg)
    assert not tracker._defer_keyframe(A, slide, A, DT, True, False, 0, TrackingConfig())


def _grid(n=26, step=0.002):
    a = (np.arange(n) - (n - 1) / 2) * step
    return np.stack(np.meshgrid(a, a), -1).reshape(-1, 2)


def test_crease_points_are_the_edge_band():
    g = _grid()
    g = g[g[:, 0] > 0]  # half planes meeting at the edge x = 0, z = 0
    top = np.c_[g[:, 0], g[:, 1], np.zeros(len(g))]
    side = np.c_[np.zeros(len(g)), g[:, 1], -g[:, 0]]
    P = np.concatenate([top, side])
    N = np.concatenate([np.tile([0.0, 0, 1], (len(g), 1)), np.tile([-1.0, 0, 0], (len(g), 1))])
    c = crease_points(P, N, 0.005, 0.85)
    d_edge = np.hypot(P[:, 0], P[:, 2])  # distance to the edge line
    assert c[d_edge < 0.0025].all()  # a neighbour on the other face within 5 mm
    assert not c[d_edge > 0.0051].any()
    # a plane alone (and a gently curved surface) has no crease
    assert not crease_points(top, N[: len(top)], 0.005, 0.85).any()
    assert not crease_points(P, N, 0.0, 0.85).any()


def test_icp_pairs_need_compatible_normals():
    g = _grid(20, 0.004)
    Q = np.c_[g, np.zeros(len(g))]
    Nq = np.tile([0.0, 0, 1], (len(Q), 1))
    tree = cKDTree(Q)
    P = Q + [0.0, 0.0, 0.002]  # the plane 2 mm above the model
    up = np.tile([0.0, 0, 1], (len(P), 1))
    side = np.tile([1.0, 0, 0], (len(P), 1))  # points of another face: their normals disagree with the model's
    r = icp(P, np.eye(4), tree, Q, Nq, N_src=up, normal_cos=0.7, w_point=0.0)
    assert abs(r.X_WO[2, 3] - 0.002) < 2e-4  # compatible: registered
    r = icp(P, np.eye(4), tree, Q, Nq, N_src=side, normal_cos=0.7, w_point=0.0)
    assert abs(r.X_WO[2, 3]) < 1e-9  # no pair: the start is kept
    r = icp(P, np.eye(4), tree, Q, Nq, N_src=side, normal_cos=0.0, w_point=0.0)
    assert abs(r.X_WO[2, 3] - 0.002) < 2e-4  # gating off: matched regardless


@pytest.mark.parametrize("change", [{"crease_dist": -0.001}, {"kf_still_speed": -0.1}, {"kf_still_max_frames": -1},
                                    {"kf_still_tilt_deg": float("nan")}])
def test_bad_strike_settings_are_refused(change):
    with pytest.raises(ValueError) as e:
        replace(TrackingConfig(), **change)
    assert next(iter(change)) in str(e.value)
