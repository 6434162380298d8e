"""Voxel SDF: trilinear query against a naive reference, mesh extraction, and sim-to-recover of a sphere."""

import numpy as np
import torch

from service.sdf import RaySet, SdfConfig, SdfGrid, extract_mesh, fit_sdf, rays_from_frame, sdf_query
from service.sdf.grid import grid_points, sdf_query_naive
from service.transforms import make_X


def _sphere_grid(r=0.05, n=24, voxel=0.008):
    origin = -voxel * (n - 1) / 2 * np.ones(3)
    P = grid_points(origin, voxel, (n, n, n))
    return SdfGrid(origin, voxel, (np.linalg.norm(P, axis=-1) - r).astype(np.float32))


def test_query_matches_naive_trilinear():
    rng = np.random.default_rng(0)
    g = SdfGrid(np.array([0.1, -0.2, 0.0]), 0.01, rng.normal(size=(5, 6, 7)).astype(np.float32))
    pts = np.array([0.1, -0.2, 0.0]) + rng.uniform(-0.01, 0.08, size=(200, 3))  # includes points outside
    np.testing.assert_allclose(sdf_query(g, pts), sdf_query_naive(g, pts), atol=1e-5)


def test_query_is_differentiable_in_values():
    from service.sdf import query_torch

    g = _sphere_grid()
    v = torch.tensor(g.values, requires_grad=True)
    s = query_torch(v, torch.tensor(g.origin_O, dtype=torch.float32), g.voxel, torch.zeros(1, 3))
    s.sum().backward()
    assert abs(float(v.grad.sum()) - 1.0) < 1e-5  # trilinear weights sum to one


def test_extract_mesh_sphere_watertight_outward():
    m = extract_mesh(_sphere_grid()).to_trimesh()
    assert m.is_watertight
    assert m.volume > 0  # outward normals
    r = np.linalg.norm(m.vertices, axis=1)
    assert abs(r.mean() - 0.05) < 0.002


def test_extract_mesh_closes_at_grid_border():
    g = _sphere_grid(r=0.5)  # sphere larger than the grid: everything inside
    m = extract_mesh(g).to_trimesh()
    assert m.is_watertight and m.volume > 0


def _render_sphere_rays(r0=0.05, n_views=6, H=60, W=80):
    K = np.array([[120.0, 0, W / 2], [0, 120.0, H / 2], [0, 0, 1]])
    parts = []
    for k in range(n_views):
        a = 2 * np.pi * k / n_views
        c = np.array([0.35 * np.cos(a), 0.35 * np.sin(a), 0.12])
        z = -c / np.linalg.norm(c)
        x = np.cross(z, [0, 0, 1.0])
        x /= np.linalg.norm(x)
        X_OC = make_X(np.stack([x, np.cross(z, x), z], 1), c)
        u, v = np.meshgrid(np.arange(W), np.arange(H))
        d = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T @ X_OC[:3, :3].T
        b, a2, cc = d @ c, (d * d).sum(-1), c @ c - r0**2
        disc = b * b - a2 * cc
        depth = np.where(disc > 0, (-b - np.sqrt(np.maximum(disc, 0))) / a2, 0.0).astype(np.float32)
        parts.append(rays_from_frame(depth, disc > 0, K, X_OC, stride=1, ring_px=6, rng=np.random.default_rng(k)))
    return RaySet.concatenate(parts)


def test_fit_sdf_recovers_sphere_from_rays():
    rays = _render_sphere_rays()
    g = fit_sdf(rays, SdfConfig.fast())
    m = extract_mesh(g)
    assert m.to_trimesh().is_watertight
    # the observed surface (upper part: cameras above the equator) within a few mm of the true sphere
    verts = m.vertices[m.vertices[:, 2] > -0.01]
    err = np.abs(np.linalg.norm(verts, axis=1) - 0.05)
    assert np.mean(err) < 0.003, np.mean(err)
    # SDF values near the surface are metric distances
    dirs = np.random.default_rng(1).normal(size=(200, 3))
    dirs[:, 2] = np.abs(dirs[:, 2])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    for rr in (0.045, 0.055):
        s = sdf_query(g, rr * dirs)
        assert abs(np.median(s) - (rr - 0.05)) < 0.003


def test_extra_loss_hook_changes_the_field():
    rays = _render_sphere_rays(n_views=3)
    cfg = SdfConfig(resolution=20, steps=40, rays_per_step=256, samples_near=4, samples_far=4)
    calls = []
    target = torch.tensor([[0.0, 0.0, 0.09]])  # outside the sphere: ask the field to be -1 cm there

    def pull(query_fn, step):
        calls.append(step)
        return 1e4 * (query_fn(target) + 0.01).pow(2).sum()

    bounds = np.array([[-0.1, -0.1, -0.1], [0.1, 0.1, 0.12]])
    g0 = fit_sdf(rays, cfg, bounds_O=bounds)
    g1 = fit_sdf(rays, cfg, bounds_O=bounds, extra_losses=[pull])
    assert calls == list(range(cfg.steps))
    assert sdf_query(g1, target.numpy())[0] < sdf_query(g0, target.numpy())[0] - 0.005


def test_rayset_shape_checks():
    import pytest

    with pytest.raises(ValueError, match="dirs_O"):
        RaySet(np.zeros((3, 3)), np.zeros((2, 3)), np.zeros(3), np.zeros(3), np.ones(3))


def test_halfspace_cuts_the_field_and_the_mesh():
    rays = _render_sphere_rays(n_views=4)
    cfg = SdfConfig(resolution=24, steps=40, rays_per_step=256, samples_near=4, samples_far=4)
    hs = np.array([0.0, 0.0, -1.0, -0.02])  # z < -0.02 is outside
    g = fit_sdf(rays, cfg, halfspace_O=hs)
    m = extract_mesh(g)
    assert m.to_trimesh().is_watertight
    assert m.vertices[:, 2].min() > -0.02 - g.voxel  # nothing below the plane
    below = np.array([[0.0, 0.0, -0.04], [0.01, 0.0, -0.035]])
    np.testing.assert_array_less(0.01, sdf_query(g, below))  # at least the distance to the plane (2 cm, 1.5 cm)
    g0 = fit_sdf(rays, cfg)
    assert extract_mesh(g0).vertices[:, 2].min() < -0.04  # without the cut the sphere's underside is closed by the hull
