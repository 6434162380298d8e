"""Sim-to-recover: poses, visible geometry and V from a small synthetic session (noise off and on).

Ground truth (ground_truth/poses.csv, mesh.obj) is read here for evaluation only; the tracker never sees it.
Poses are compared after the fixed body-frame offset X_OG = X_WO(0)⁻¹ X_WG(0).
"""

from pathlib import Path

import numpy as np
import pytest
import trimesh

from service.session import load_session
from service.tracking import TrackingConfig, TrackingInputs, run
from service.tracking.tracker import interpolate_untracked
from service.transforms import X_inv, make_X, pose_errors, so3_exp, xyzquat_to_pose


@pytest.fixture(scope="module", params=[False, True], ids=["clean", "noisy"])
def tracked_session(request, tmp_path_factory):
    from service.synth import SynthSpec, make_session

    noise = request.param
    spec = SynthSpec(object="baking_box", seed=101, preset="tiny", occlusion="heavy", noise=noise,
                     resolution=(240, 180), n_frames=32)
    res = make_session(spec, tmp_path_factory.mktemp("trk") / "s")
    s = load_session(res.session_dir, "test")
    out = run(TrackingInputs(s), TrackingConfig.fast())
    gt = np.loadtxt(res.session_dir / "ground_truth" / "poses.csv", delimiter=",", skiprows=1)
    X_WG = xyzquat_to_pose(gt[:, 1:8])
    mesh_G = trimesh.load(res.session_dir / "ground_truth" / "mesh.obj", force="mesh")
    return noise, s, out, X_WG, mesh_G


def test_poses_recovered(tracked_session):
    noise, s, out, X_WG, _ = tracked_session
    assert out.X_WO.shape == (s.n_frames, 4, 4) and out.tracked.shape == (s.n_frames,)
    np.testing.assert_allclose(out.X_WO[0, :3, :3], np.eye(3), atol=1e-12)  # O axes parallel to W at frame 0
    X_OG = X_inv(out.X_WO[0]) @ X_WG[0]
    et, er = pose_errors(out.X_WO @ X_OG, X_WG)
    er = np.degrees(er)
    med_r, max_r, med_t, max_t = (4.0, 12.0, 0.004, 0.010) if noise else (1.5, 6.0, 0.002, 0.006)
    assert np.median(er) < med_r and er.max() < max_r, (np.median(er), er.max())
    assert np.median(et) < med_t and et.max() < max_t, (np.median(et), et.max())
    assert out.tracked.mean() > 0.9
    assert out.frames_lost == int((~out.tracked).sum())


def test_origin_is_centroid_of_first_frame_points(tracked_session):
    _, s, out, _, _ = tracked_session
    d, m, K = s.depth(0), s.mask(0), s.K
    v, u = np.nonzero(m & (d > 0))
    z = d[v, u]
    P_C = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], 1)
    c_W = (P_C @ s.X_WC[:3, :3].T + s.X_WC[:3, 3]).mean(0)
    assert np.linalg.norm(out.X_WO[0, :3, 3] - c_W) < 0.01  # robust subset of the same points


def test_visible_geometry_on_true_surface(tracked_session):
    _, _, out, X_WG, mesh_G = tracked_session
    X_GO = X_inv(X_inv(out.X_WO[0]) @ X_WG[0])
    m = out.visible_mesh.to_trimesh()
    assert m.is_watertight and m.volume > 0
    V_G = out.visible_points_O @ X_GO[:3, :3].T + X_GO[:3, 3]
    assert len(V_G) > 50
    _, dV, _ = trimesh.proximity.closest_point(mesh_G, V_G)
    assert np.mean(dV) < 0.004, np.mean(dV)
    # observed part of the visible mesh lies on the true surface
    from service.sdf.grid import sdf_query  # noqa: F401  (public query used by fusion)

    verts_G = m.vertices @ X_GO[:3, :3].T + X_GO[:3, 3]
    _, dm, _ = trimesh.proximity.closest_point(mesh_G, verts_G)
    assert np.median(dm) < 0.004, np.median(dm)
    assert out.v_WO_W.shape == (len(out.t), 3) and out.w_WO_O.shape == (len(out.t), 3)


def test_interpolate_untracked():
    X = np.stack([make_X(so3_exp([0, 0, 0.1 * i]), [0.01 * i, 0, 0]) for i in range(5)])
    tracked = np.array([True, False, False, True, True])
    Xi = interpolate_untracked(X, tracked)
    et, er = pose_errors(Xi, X)
    assert et.max() < 1e-12 and er.max() < 1e-9


def test_plots(tracked_session, tmp_path):
    from service.tracking import plots

    _, s, out, X_WG, _ = tracked_session
    fig = plots.pose_error_figure(out.t, out.X_WO, X_WG, out.tracked, path=tmp_path / "err.png")
    assert (tmp_path / "err.png").stat().st_size > 1000 and len(fig.axes) == 2
    plots.velocity_figure(out, path=tmp_path / "vel.png")
    img = plots.overlay_frames(s, out, [0, s.n_frames - 1], path=tmp_path / "ov.png")
    assert img.shape == (s.height, 2 * s.width, 3) and (tmp_path / "ov.png").is_file()
    et, _ = plots.pose_errors_vs_reference(out.X_WO, X_WG)
    assert et[0] < 1e-9


def test_nothing_below_the_table(tracked_session):
    _, s, out, _, _ = tracked_session
    z_W = out.visible_mesh.vertices @ out.X_WO[0, 2, :3] + out.X_WO[0, 2, 3]  # frame-0 height of the mesh
    assert z_W.min() > s.table_height - out.sdf.voxel, (z_W.min(), s.table_height)
    zV = out.visible_points_O @ out.X_WO[0, 2, :3] + out.X_WO[0, 2, 3]
    assert zV.min() >= s.table_height - 1e-6


def test_free_space_rejects_points_seen_through():
    from service.tracking.tracker import FreeSpace

    K = np.array([[100.0, 0, 40], [0, 100.0, 30], [0, 0, 1]])
    depth = np.zeros((60, 80), np.float32)
    depth[:, :] = 1.0  # a wall 1 m in front of the camera
    depth[20:40, 30:50] = 0.5  # an object patch at 0.5 m
    fs = FreeSpace(K, np.eye(4), margin=0.01, px=1)
    fs.add(0, depth, np.eye(4))  # O = W = C
    P = np.array([[0.0, 0.0, 0.5],   # on the patch: kept
                  [0.0, 0.0, 0.7],   # behind the patch: hidden, kept
                  [-0.12, 0.0, 0.6],  # in front of the wall beside the patch (pixel 20): seen through
                  [-0.24, 0.0, 1.2],  # behind the wall: kept
                  [-0.055, 0.0, 0.5]])  # one pixel outside the patch (29): the min filter keeps the rim
    np.testing.assert_array_equal(fs.seen_through(P), [False, False, True, False, False])


def test_near_effector_only_with_robot_data(tracked_session):
    from service.tracking.tracker import near_effector

    _, s, _, _, _ = tracked_session
    cfg = TrackingConfig()
    c = s.p_WE[3]
    P = c + np.array([[s.ee_radius + 0.001, 0, 0], [s.ee_radius + cfg.ee_margin + 0.002, 0, 0]])
    assert len(s.robot_t) > 0
    np.testing.assert_array_equal(near_effector(s, 3, P, cfg), [True, False])
    from dataclasses import replace

    np.testing.assert_array_equal(near_effector(replace(s, robot_t=np.zeros(0)), 3, P, cfg), [False, False])
