import numpy as np
import pytest
import trimesh

from service.evaluation.geometry import chamfer, chamfer_naive, icp, occupancy, sample_surface, voxel_iou
from service.mesh import Mesh
from service.transforms import X_inv, make_X, pose_errors, so3_exp, transform_points


def M(t):
    return Mesh.from_trimesh(t)


def test_chamfer_matches_naive_reference():
    rng = np.random.default_rng(1)
    A, B = rng.normal(size=(300, 3)), rng.normal(size=(250, 3)) + 0.1
    assert chamfer(A, B) == pytest.approx(chamfer_naive(A, B), rel=1e-12)


def test_chamfer_of_a_mesh_with_itself():
    m = M(trimesh.creation.box((0.1, 0.06, 0.12)))
    A = sample_surface(m, 2000, seed=0)
    assert chamfer(A, sample_surface(m, 2000, seed=0)) == 0.0
    # independent samples of the same surface: only the sampling spacing remains (≈ 2 mm here)
    assert chamfer(A, sample_surface(m, 2000, seed=1)) < 0.003


def test_chamfer_of_concentric_spheres_is_the_radius_difference():
    a = M(trimesh.creation.icosphere(subdivisions=4, radius=0.10))
    b = M(trimesh.creation.icosphere(subdivisions=4, radius=0.14))
    d = chamfer(sample_surface(a, 2000, 0), sample_surface(b, 2000, 1))
    assert d == pytest.approx(0.04, rel=0.05)


def test_component_sampling_gives_small_pieces_ten_points():
    big = trimesh.creation.box((0.1, 0.1, 0.1))
    small = trimesh.creation.box((0.01, 0.01, 0.01))
    small.apply_translation([0.2, 0, 0])
    pts = sample_surface(M(trimesh.util.concatenate([big, small])), 2000, 0, split_components=True)
    assert len(pts) == 2000
    assert (pts[:, 0] > 0.15).sum() == 10


def test_iou_of_offset_boxes_is_analytic():
    a = trimesh.creation.box((0.1, 0.1, 0.1))
    b = trimesh.creation.box((0.1, 0.1, 0.1))
    b.apply_translation([0.03, 0.0, 0.0])
    r = voxel_iou(M(a), M(b), pitch=0.002)
    assert r.iou == pytest.approx(0.07 / 0.13, abs=0.02)
    assert r.volume_a == pytest.approx(1e-3, rel=0.05)
    assert voxel_iou(M(a), M(a)).iou == 1.0


def test_occupancy_agrees_with_an_independent_inside_test():
    m = trimesh.creation.annulus(r_min=0.02, r_max=0.05, height=0.04)  # non-convex
    origin, pitch, shape = np.array([-0.06, -0.06, -0.03]), 0.004, (30, 30, 15)
    occ = occupancy(M(m), origin, pitch, shape)
    idx = np.stack(np.meshgrid(*[np.arange(s) for s in shape], indexing="ij"), -1).reshape(-1, 3)
    centres = origin + pitch * idx
    r = np.linalg.norm(centres[:, :2], axis=1)
    ref = (r > 0.02) & (r < 0.05) & (np.abs(centres[:, 2]) < 0.02)
    # the polygonal annulus differs from the analytic one only in a thin shell near the surface
    assert (occ.reshape(-1) != ref).mean() < 0.02


def test_icp_recovers_a_known_small_transform():
    rng = np.random.default_rng(0)
    shape = trimesh.convex.convex_hull(rng.normal(size=(40, 3)) * [0.06, 0.04, 0.03])
    X_true = make_X(so3_exp(np.array([0.03, -0.05, 0.08])), [0.008, -0.005, 0.004])
    target = transform_points(X_true, sample_surface(M(shape), 2000, 0))
    res = icp(sample_surface(M(shape), 2000, 1), target, np.eye(4), max_corr=0.02, max_iter=200)
    dt, dr = pose_errors(res.X[None], X_true[None])
    assert dt[0] < 1.5e-3 and np.degrees(dr[0]) < 1.5
    assert res.fitness > 0.95
    # the inverse direction from the inverse start is also recovered
    res2 = icp(target, sample_surface(M(shape), 2000, 2), np.eye(4), max_iter=200)
    dt2, _ = pose_errors(res2.X[None], X_inv(X_true)[None])
    assert dt2[0] < 1.5e-3
