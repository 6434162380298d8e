"""Physible sample generation against its definitions and a naive anchor filter."""

from __future__ import annotations

import numpy as np
import pytest

from service.fusion.samples import (
    hyperplane_anchors,
    hyperplane_samples,
    inside_box,
    ray_samples,
    tangent_frames,
)
from service.fusion.types import SampleExtents
from tests.fusion.scenes import HALF, box_mesh, face_points

EXT = SampleExtents(ray_n_in=7, ray_n_out=5, ray_n_far=3, hc_n_in=6, hc_n_near=4, hc_n_far=2)


def unit(v):
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_ray_samples_lie_on_rays_with_their_signed_distance():
    rng = np.random.default_rng(0)
    P = rng.normal(size=(11, 3))
    N = unit(rng.normal(size=(11, 3)))
    x, l = ray_samples(P, 3.0 * N, EXT, rng)  # normals are normalised inside
    k = EXT.ray_n_in + EXT.ray_n_out + EXT.ray_n_far
    assert x.shape == (11 * k, 3) and l.shape == (11 * k,)
    x, l = x.reshape(11, k, 3), l.reshape(11, k)
    assert np.allclose(x, P[:, None] + l[..., None] * N[:, None], atol=1e-12)
    a, b = EXT.ray_n_in, EXT.ray_n_in + EXT.ray_n_out
    assert np.all((l[:, :a] <= 0) & (l[:, :a] >= -EXT.ray_d_in))
    assert np.all((l[:, a:b] >= 0) & (l[:, a:b] <= EXT.ray_d_out))
    assert np.all((l[:, b:] >= 0) & (l[:, b:] <= EXT.ray_d_far))


def test_ray_samples_reject_bad_normals():
    with pytest.raises(ValueError):
        ray_samples(np.zeros((2, 3)), np.zeros((2, 3)), EXT, np.random.default_rng(0))
    with pytest.raises(ValueError):
        ray_samples(np.zeros((2, 3)), np.ones((3, 3)), EXT, np.random.default_rng(0))


def test_tangent_frames_orthonormal():
    rng = np.random.default_rng(1)
    N = unit(np.vstack([rng.normal(size=(20, 3)), [[1.0, 0, 0], [0, 0, -1.0]]]))
    t1, t2 = tangent_frames(N, rng)
    for a, b in [(t1, t2), (t1, N), (t2, N)]:
        assert np.allclose((a * b).sum(1), 0, atol=1e-12)
    for a in (t1, t2):
        assert np.allclose(np.linalg.norm(a, axis=1), 1)


def test_hyperplane_samples_cylinders():
    rng = np.random.default_rng(2)
    V = rng.normal(size=(9, 3))
    M = unit(rng.normal(size=(9, 3)))
    q, b = hyperplane_samples(V, M, EXT, rng)
    k = EXT.hc_n_in + EXT.hc_n_near + EXT.hc_n_far
    q, b = q.reshape(9, k, 3), b.reshape(9, k)
    d = q - V[:, None]
    h = (d * M[:, None]).sum(-1)
    assert np.allclose(h, b, atol=1e-12)  # bound = (q − v)·m̂
    r = np.linalg.norm(d - h[..., None] * M[:, None], axis=-1)
    g1, g2 = EXT.hc_n_in, EXT.hc_n_in + EXT.hc_n_near
    assert np.all((b[:, :g1] >= -EXT.hc_h_in) & (b[:, :g1] <= 0) & (r[:, :g1] <= EXT.hc_r_near + 1e-12))
    assert np.all((b[:, g1:g2] >= 0) & (b[:, g1:g2] <= EXT.hc_h_near) & (r[:, g1:g2] <= EXT.hc_r_near + 1e-12))
    assert np.all((b[:, g2:] >= 0) & (b[:, g2:] <= EXT.hc_h_far) & (r[:, g2:] <= EXT.hc_r_far + 1e-12))


def anchors_naive(x, m, P, N, tol):
    keep = []
    for xi, mi in zip(x, m):
        d = [abs(np.dot(xi - p, n)) for p, n in zip(P, N)]
        i = int(np.argmin(d))
        keep.append(d[i] < tol and np.dot(mi, N[i]) > 0)
    return np.array(keep)


def test_hyperplane_anchors_match_naive_filter():
    rng = np.random.default_rng(3)
    P, N = face_points(5, 2, -1.0, rng)  # contacts on the bottom face, normal −z
    A, M = hyperplane_anchors(box_mesh(), P, N, np.random.default_rng(4), n_surface=3000, tol=1e-3)
    assert len(A) > 100
    assert np.allclose(A[:, 2], -HALF[2], atol=1e-9)
    assert np.allclose(M, [0, 0, -1.0])
    # same random surface samples through the naive filter
    import trimesh

    r2 = np.random.default_rng(4)
    tm = box_mesh().to_trimesh()
    area = tm.area_faces
    face = r2.choice(len(area), size=3000, p=area / area.sum())
    tri = tm.triangles[face]
    u, v = r2.random(3000), r2.random(3000)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    x = tri[:, 0] + u[:, None] * (tri[:, 1] - tri[:, 0]) + v[:, None] * (tri[:, 2] - tri[:, 0])
    keep = anchors_naive(x, tm.face_normals[face], P, N, 1e-3)
    assert np.allclose(A, x[keep])
    assert isinstance(tm, trimesh.Trimesh)


def test_hyperplane_anchors_need_aligned_normals():
    rng = np.random.default_rng(5)
    P, N = face_points(5, 2, -1.0, rng)
    A, _ = hyperplane_anchors(box_mesh(), P, -N, rng, n_surface=2000)  # plane right, normal flipped
    assert len(A) == 0
    A, _ = hyperplane_anchors(box_mesh(), np.zeros((0, 3)), np.zeros((0, 3)), rng)
    assert len(A) == 0


def test_inside_box():
    b = np.array([[0.0, 0, 0], [1.0, 1, 1]])
    x = np.array([[0.5, 0.5, 0.5], [1.5, 0.5, 0.5], [0, 0, 0], [0.5, -0.1, 0.5]])
    assert inside_box(x, b).tolist() == [True, False, True, False]
