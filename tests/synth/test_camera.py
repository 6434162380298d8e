"""Camera conventions against a naive reference: TinyRenderer depth equals ray-plane intersection."""

import numpy as np
import pybullet as pb
import pytest

from service.synth.camera import backproject, gl_projection_matrix, gl_view_matrix, intrinsics, linearize_depth, look_at
from service.transforms import mat_to_quat, quat_to_xyzw, so3_exp


def _render(cid, K, X_WC, W, H):
    _, _, _, d, seg = pb.getCameraImage(W, H, viewMatrix=gl_view_matrix(X_WC), projectionMatrix=gl_projection_matrix(K, W, H),
                                       renderer=pb.ER_TINY_RENDERER, physicsClientId=cid)
    return linearize_depth(np.asarray(d, float).reshape(H, W)), np.asarray(seg).reshape(H, W)


@pytest.fixture(scope="module")
def plane_scene():
    cid = pb.connect(pb.DIRECT)
    R = so3_exp(np.array([0.45, -0.3, 0.2]))
    q = mat_to_quat(R)
    v = pb.createVisualShape(pb.GEOM_BOX, halfExtents=[1.0, 1.0, 0.01], physicsClientId=cid)
    pb.createMultiBody(0, -1, v, [0.5, 0.0, 0.0], quat_to_xyzw(q), physicsClientId=cid)
    n = R[:, 2]
    p0 = np.array([0.5, 0.0, 0.0]) + 0.01 * n
    yield cid, n, p0
    pb.disconnect(physicsClientId=cid)


@pytest.mark.parametrize("W,H", [(160, 120), (640, 480)])
def test_depth_matches_ray_plane_intersection(plane_scene, W, H):
    cid, n, p0 = plane_scene
    K = intrinsics(W, H)
    X_WC = look_at(np.array([0.3, -0.6, 0.7]), np.array([0.5, 0.0, 0.0]))
    z, _ = _render(cid, K, X_WC, W, H)
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    rays_W = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones(u.shape)], -1) @ X_WC[:3, :3].T
    ref = ((p0 - X_WC[:3, 3]) @ n) / (rays_W @ n)  # z-depth, the ray has unit z in C
    ok = z > 0
    assert ok.mean() > 0.9
    assert np.abs(z[ok] - ref[ok]).max() < 5e-5
    # and a half-pixel shift would be visible: the reference at (u + 0.5) differs by far more
    rays_s = np.stack([(u + 0.5 - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones(u.shape)], -1) @ X_WC[:3, :3].T
    ref_s = ((p0 - X_WC[:3, 3]) @ n) / (rays_s @ n)
    assert np.median(np.abs(z[ok] - ref_s[ok])) > 20 * np.median(np.abs(z[ok] - ref[ok]))
    # back-projection puts the points on the plane
    p_C = backproject(z, K)
    p_W = p_C @ X_WC[:3, :3].T + X_WC[:3, 3]
    assert np.abs((p_W - p0) @ n).max() < 5e-5


def test_sub_window_equals_crop_of_full_render(plane_scene):
    cid, _, _ = plane_scene
    W, H = 160, 120
    K = intrinsics(W, H)
    X_WC = look_at(np.array([0.3, -0.6, 0.7]), np.array([0.5, 0.0, 0.0]))
    z, _ = _render(cid, K, X_WC, W, H)
    u0, v0, u1, v1 = 37, 21, 101, 77
    Ks = K.copy()
    Ks[0, 2] -= u0
    Ks[1, 2] -= v0
    zs, _ = _render(cid, Ks, X_WC, u1 - u0, v1 - v0)
    assert np.allclose(zs, z[v0:v1, u0:u1], atol=1e-6)


def test_look_at_is_opencv():
    eye, target = np.array([0.5, -0.7, 0.5]), np.array([0.5, 0.0, 0.0])
    X = look_at(eye, target)
    R = X[:3, :3]
    assert np.allclose(R.T @ R, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
    assert np.allclose(R[:, 2], (target - eye) / np.linalg.norm(target - eye))  # z forward
    assert R[2, 1] < 0  # image y (down) points down in the world
    assert np.isclose(R[2, 0], 0.0)  # x right stays horizontal
