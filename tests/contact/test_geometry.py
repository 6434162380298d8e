"""Deep support function properties, mesh export and closest points on the hull."""

import numpy as np
import torch

from service.contact.geometry import (
    HomogeneousICNN,
    closest_point_on_hull,
    cube_surface_directions,
    export_mesh,
    hull_mesh,
    outward_directions_to,
    pretrain_to_points,
)
from service.contact.simulate import box_vertices


def _net(seed=0, width=48):
    return HomogeneousICNN(width, 0.1, torch.Generator().manual_seed(seed))


def test_homogeneous_convex_and_gradient_is_support_point():
    net = _net()
    g = torch.Generator().manual_seed(1)
    d = torch.randn(300, 3, generator=g, dtype=torch.float64)
    e = torch.randn(300, 3, generator=g, dtype=torch.float64)
    f = net.support_value(d)
    for a in (0.3, 2.0, 7.5):
        assert torch.allclose(net.support_value(a * d), a * f, rtol=1e-10, atol=1e-14)
        assert torch.allclose(net(a * d), net(d), atol=1e-12)  # s(d) is degree-0 homogeneous
    assert (net.support_value(0.5 * (d + e)) <= 0.5 * (f + net.support_value(e)) + 1e-12).all()
    # analytic gradient equals autograd's
    dd = d.clone().requires_grad_(True)
    (gd,) = torch.autograd.grad(net.support_value(dd).sum(), dd)
    assert torch.allclose(net(d), gd, atol=1e-12)
    # Euler: f(d) = d·s(d); and s(d) is a maximiser over the other support points
    assert torch.allclose((net(d) * d).sum(-1), f, atol=1e-12)
    S = net(e)
    assert ((d @ S.T) <= f.unsqueeze(-1) + 1e-10).all()


def test_support_points_differentiable_in_weights():
    net = _net()
    s = net(torch.tensor([[0.0, 0.0, -1.0]], dtype=torch.float64))
    s.sum().backward()
    assert net.w.grad is not None and net.w.grad.abs().sum() > 0
    assert net.A1.grad.abs().sum() > 0 and net.H2.grad.abs().sum() > 0


def test_export_mesh_is_closed_and_outward():
    net = _net(width=32)
    d = cube_surface_directions(8)
    assert len(d) == 296
    mesh, s = export_mesh(net, d)
    tm = mesh.to_trimesh()
    assert tm.is_watertight and tm.volume > 0
    # every support point lies on or inside the hull
    _, sd = closest_point_on_hull(mesh, s)
    assert (sd <= 1e-9).all()


def test_closest_point_matches_trimesh():
    import trimesh

    rng = np.random.default_rng(0)
    mesh = hull_mesh(rng.normal(size=(40, 3)) * [0.05, 0.03, 0.04])
    p = rng.normal(size=(300, 3)) * 0.06
    cp, sd = closest_point_on_hull(mesh, p)
    tm = mesh.to_trimesh()
    cp_ref, dist_ref, _ = trimesh.proximity.closest_point(tm, p)
    sd_ref = trimesh.proximity.signed_distance(tm, p)  # trimesh: positive inside
    assert np.allclose(np.abs(sd), dist_ref, atol=1e-9)
    assert np.allclose(cp, cp_ref, atol=1e-7)
    assert np.allclose(sd, -sd_ref, atol=1e-7)
    _, _, n = outward_directions_to(mesh, p)
    assert np.allclose(np.linalg.norm(n, axis=-1), 1)


def test_pretrain_fits_a_box():
    net = HomogeneousICNN(32, 0.1, torch.Generator().manual_seed(0))
    h = np.array([0.04, 0.03, 0.02])
    torch.manual_seed(0)
    err = pretrain_to_points(net, box_vertices(h), steps=200, n_dirs=300)
    mesh, _ = export_mesh(net, cube_surface_directions(8))
    half = 0.5 * np.ptp(mesh.vertices, axis=0)
    assert err < 2e-3
    assert np.allclose(half, h, rtol=0.15)


def test_closest_point_with_candidate_faces_matches_exact_near_the_surface():
    rng = np.random.default_rng(1)
    d = rng.normal(size=(300, 3))
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    mesh = hull_mesh(d * [0.05, 0.03, 0.02])
    # points from well inside to 60 % outside the surface (visible points, sphere centres)
    p = rng.normal(size=(800, 3)) * [0.05, 0.03, 0.02] * rng.uniform(0.3, 1.6, (800, 1))
    cp, sd = closest_point_on_hull(mesh, p)
    cp_k, sd_k = closest_point_on_hull(mesh, p, candidates=12)
    assert (sd < 0).any() and (sd > 0).any()
    assert np.allclose(cp_k, cp, atol=1e-9) and np.allclose(sd_k, sd, atol=1e-9)
    n = outward_directions_to(mesh, p)[2]
    n_k = outward_directions_to(mesh, p, candidates=12)[2]
    assert np.allclose(n_k, n, atol=1e-7)


def test_polytope_support_and_local_gradient():
    from service.contact.geometry import PolytopeSupport
    from service.contact.learn import polytope_init

    V = polytope_init(box_vertices([0.04, 0.03, 0.02]), 0.1, 50)
    poly = PolytopeSupport(V)
    d = torch.as_tensor(cube_surface_directions(6))
    s = poly(d)
    # support points are box corners, f(d) = d·s(d) = Σ|d_i| h_i
    assert torch.allclose(s.abs(), torch.tensor([0.04, 0.03, 0.02], dtype=torch.float64).expand_as(s))
    assert torch.allclose(poly.support_value(d), (d.abs() * torch.tensor([0.04, 0.03, 0.02])).sum(-1))
    # a loss on one direction moves only the vertex that is its support point
    q = torch.tensor([[0.3, 0.5, -0.8]], dtype=torch.float64)
    poly.support_value(q).sum().backward()
    moved = (poly.V.grad.abs().sum(-1) > 0).nonzero().squeeze(-1)
    assert len(moved) == 1 and torch.allclose(poly.V.grad[moved[0]], q[0])
    mesh, _ = export_mesh(poly, cube_surface_directions(8))
    assert np.allclose(np.ptp(mesh.vertices, axis=0), [0.08, 0.06, 0.04])
    # ball initialisation without a guess
    B = polytope_init(None, 0.05, 100)
    assert B.shape == (100, 3) and np.allclose(np.linalg.norm(B, axis=-1), 0.05)
