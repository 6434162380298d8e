"""Free-space votes of points against depth images, and the table-contact classification of physible points."""

from __future__ import annotations

import numpy as np

from service.fusion.carve import free_space_votes, min_depth
from service.fusion.stage import table_contacts

K = np.array([[50.0, 0, 19.5], [0, 50.0, 14.5], [0, 0, 1]])


def wall(depth: float, hole: tuple[slice, slice] | None = None) -> np.ndarray:
    D = np.full((30, 40), depth, np.float32)
    if hole is not None:
        D[hole] = 0.0
    return D


def test_min_depth_is_a_window_minimum_and_zero_spreads():
    D = wall(1.0)
    D[10, 10] = 0.5
    D[20, 30] = 0.0
    m = min_depth(D, 1)
    assert m[9, 9] == 0.5 and m[11, 11] == 0.5 and m[12, 12] == 1.0
    assert m[19, 29] == 0.0 and m[21, 31] == 0.0 and m[22, 32] == 1.0
    assert np.array_equal(min_depth(D, 0), D)


def test_points_in_front_of_a_reading_are_free_behind_are_not():
    X_OC = np.eye(4)  # camera at O's origin looking along +z
    pts = np.array([[0, 0, 0.5], [0, 0, 0.995], [0, 0, 1.5], [0, 0, -0.5], [10.0, 0, 1.0]])
    free, obs = free_space_votes(pts, [wall(1.0)], [X_OC], K, margin=0.01, radius_px=1)
    assert free.tolist() == [1, 0, 0, 0, 0]  # in front; within the margin; behind; behind the camera; off-image
    assert obs.tolist() == [1, 1, 1, 0, 0]
    # a missing reading near the pixel is no evidence
    free, obs = free_space_votes(pts[:1], [wall(1.0, (slice(14, 16), slice(20, 21)))], [X_OC], K, radius_px=1)
    assert free.tolist() == [0] and obs.tolist() == [0]
    # two frames, the second one with the camera moved behind the point: counted per frame
    X2 = np.eye(4)
    X2[2, 3] = 0.8
    free, obs = free_space_votes(pts[:1], [wall(1.0), wall(1.0)], [X_OC, X2], K, margin=0.01, radius_px=0)
    assert free.tolist() == [1] and obs.tolist() == [1]


def test_table_contacts_need_the_downward_normal_at_table_height():
    X_WO = np.repeat(np.eye(4)[None], 3, 0)
    X_WO[:, 2, 3] = 0.02  # O 2 cm above the table (z = 0)
    c, s = np.cos(0.3), np.sin(0.3)
    X_WO[2, :3, :3] = [[1, 0, 0], [0, c, -s], [0, s, c]]  # tilted about x in the last frame
    tracked = np.array([True, True, True])
    down_tilted = -X_WO[2, 2, :3]
    P = np.array([[0.01, 0.0, -0.02], [0.01, 0.0, -0.02], [0.03, 0.0, 0.0], [0.0, 0.0, -0.05],
                  -0.02 * down_tilted / np.linalg.norm(down_tilted) * -1])
    N = np.array([[0, 0, -1.0], [1.0, 0, 0], [0, 0, -1.0], [0, 0, -1.0], down_tilted])
    got = table_contacts(P, N, X_WO, tracked, table_height=0.0)
    # on the table with the table's normal; a sphere contact (sideways); -z but 2 cm above the table;
    # -z but 3 cm below it; the tilted frame's normal at its table height
    assert got.tolist() == [True, False, False, False, True]
    assert not table_contacts(P, N, X_WO, np.array([False, False, True]), 0.0)[0]  # only tracked frames count
    assert table_contacts(np.zeros((0, 3)), np.zeros((0, 3)), X_WO, tracked, 0.0).shape == (0,)


def test_penetrating_points_below_the_table_or_inside_the_end_effector():
    from service.fusion.stage import penetrating

    X_WO = np.repeat(np.eye(4)[None], 2, 0)
    X_WO[:, 2, 3] = 0.02
    c, s = np.cos(0.5), np.sin(0.5)
    X_WO[1, :3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]  # tilted about y in the second frame
    p_WE = np.array([[0.10, 0.0, 0.06], [np.nan, np.nan, np.nan]])  # sphere only known in frame 0
    P = np.array([
        [0.0, 0.0, -0.02],   # on the table in frame 0, above it in frame 1 (tilt about the origin)
        [0.0, 0.0, -0.03],   # 1 cm below the table in frame 0
        [0.04, 0.0, -0.02],  # on the table at frame 0, sinks 1.7 cm below it in the tilted frame 1
        [0.09, 0.0, 0.04],   # inside the sphere (radius 2 cm) in frame 0
        [0.075, 0.0, 0.04],  # 5 mm outside it
    ])
    got = penetrating(P, X_WO, np.array([True, True]), 0.0, p_WE, 0.02, tol=0.003)
    assert got.tolist() == [False, True, True, True, False]
    # untracked frames do not count; without the robot only the table does
    assert penetrating(P, X_WO, np.array([True, False]), 0.0, p_WE, 0.02, tol=0.003).tolist() == [False, True, False, True, False]
    assert penetrating(P, X_WO, np.array([True, True]), 0.0, None, 0.0, tol=0.003).tolist() == [False, True, True, False, False]


FIN_C, FIN_H = np.array([0.047, 0.0, 0.0]), np.array([0.017, 0.003, 0.012])  # fin: x 3.0-6.4 cm, 6 mm thick


def _box_with_fin_grid(voxel: float = 0.004):
    """SDF grid (in O) of the scenes' box with a thin fin sticking 2.4 cm out of its +x face, 6 mm thick."""
    from service.sdf.grid import grid_points
    from service.sdf.types import SdfGrid
    from tests.fusion.scenes import box_sdf

    origin = np.array([-0.07, -0.06, -0.05])
    shape = tuple(int(round(e / voxel)) + 1 for e in (0.14, 0.12, 0.10))
    P = grid_points(origin, voxel, shape).reshape(-1, 3)
    fin = box_sdf(P - FIN_C, half=FIN_H)
    S = np.minimum(box_sdf(P), fin).reshape(shape).astype(np.float32) + np.float32(1e-5)  # no exact zeros
    return SdfGrid(origin_O=origin, voxel=voxel, values=S)


def _render(eye, W=80, H=60, wall=1.0):
    """Depth (H,W) of the bare box (no fin) in front of a wall at camera depth ``wall``, and X_OC."""
    from tests.fusion.scenes import look_at, ray_box

    X = look_at(np.asarray(eye, float))
    Kc = np.array([[70.0, 0, (W - 1) / 2], [0, 70.0, (H - 1) / 2], [0, 0, 1]])
    uu, vv = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    d_C = np.stack([uu.ravel(), vv.ravel(), np.ones(uu.size)], 1) @ np.linalg.inv(Kc).T
    t = ray_box(np.repeat(X[None, :3, 3], len(d_C), 0), d_C @ X[:3, :3].T)
    return np.where(np.isfinite(t), t, wall).reshape(H, W).astype(np.float32), X, Kc


def test_carve_grid_removes_a_fin_the_camera_sees_through_and_keeps_the_box():
    from service.fusion.carve import carve_grid
    from service.sdf import extract_mesh
    from tests.fusion.scenes import box_sdf

    g = _box_with_fin_grid()
    frames = [_render(e) for e in ([0.35, -0.30, 0.25], [0.40, 0.25, 0.30], [0.05, -0.45, 0.20])]
    out, n = carve_grid(g, [f[0] for f in frames], [f[1] for f in frames], frames[0][2], margin=0.006,
                        radius_px=1, min_frac=0.2)
    assert n > 0
    before, after = extract_mesh(g).to_trimesh(), extract_mesh(out).to_trimesh()
    assert before.bounds[1, 0] > 0.06  # the fin reaches 6.4 cm
    # carved back to the +x face (4 cm), up to the margin: within 6 mm in front of a reading is no evidence
    assert after.bounds[1, 0] < 0.04 + 0.006 + g.voxel
    assert abs(after.volume - 0.08 * 0.06 * 0.04) < 0.1 * 0.08 * 0.06 * 0.04
    # no voxel of the true box was carved: S' = S there
    from service.sdf.grid import grid_points

    P = grid_points(g.origin_O, g.voxel, g.shape).reshape(-1, 3)
    inside = box_sdf(P) < -g.voxel
    assert np.array_equal(out.values.reshape(-1)[inside], g.values.reshape(-1)[inside])
    # the carved field stays a distance-like field: ≥ 0 on the fin, equal to S away from it
    fin = box_sdf(P - FIN_C, half=FIN_H) < 0
    assert np.all(out.values.reshape(-1)[fin & (P[:, 0] > 0.04 + 0.006 + g.voxel)] > 0)


def test_carve_grid_keeps_what_no_camera_saw_through():
    from service.fusion.carve import carve_grid

    g = _box_with_fin_grid()
    # a camera behind the −x face: the box hides the fin; and one far camera with no reading at all
    d, X, Kc = _render([-0.45, 0.0, 0.05])
    out, n = carve_grid(g, [d, np.zeros_like(d)], [X, X], Kc, margin=0.006, radius_px=1, min_frac=0.2)
    assert n == 0 and out is g
    # two frames needed, one given: nothing carved
    d, X, Kc = _render([0.35, -0.30, 0.25])
    out, n = carve_grid(g, [d], [X], Kc, margin=0.006, radius_px=1, min_frac=0.2, min_frames=2)
    assert n == 0


def test_open_unsupported_removes_a_thin_fin_without_evidence_and_keeps_a_seen_one():
    from service.fusion.carve import open_unsupported
    from service.sdf import extract_mesh
    from service.sdf.grid import grid_points
    from tests.fusion.scenes import box_sdf

    g = _box_with_fin_grid(voxel=0.002)
    P = grid_points(g.origin_O, g.voxel, g.shape).reshape(-1, 3)
    on_box = P[np.abs(box_sdf(P)) < 0.001]  # evidence on the box surface only
    out, n = open_unsupported(g, on_box, radius=0.004, support=0.004)
    assert n > 0
    after = extract_mesh(out).to_trimesh()
    assert after.bounds[1, 0] < 0.04 + 0.004 + g.voxel  # the fin is gone up to the support distance
    inside = box_sdf(P) < -0.001  # the box stays solid (values near the fin's root may rise, never to > 0)
    assert np.all(out.values.reshape(-1)[inside] < 0)
    # evidence on the fin too (e.g. depth points on a real thin wall): nothing of it is removed
    fin_surface = P[np.abs(box_sdf(P - FIN_C, half=FIN_H)) < 0.001]
    out2, n2 = open_unsupported(g, np.concatenate([on_box, fin_surface]), radius=0.004, support=0.004)
    assert extract_mesh(out2).to_trimesh().bounds[1, 0] > 0.06
    # no evidence at all: only thin parts go, the box stays
    out3, _ = open_unsupported(g, np.zeros((0, 3)), radius=0.004, support=0.004)
    assert abs(extract_mesh(out3).to_trimesh().volume - 0.08 * 0.06 * 0.04) < 0.1 * 0.08 * 0.06 * 0.04
