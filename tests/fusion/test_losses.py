"""Contact-induced SDF losses against naive per-sample references and analytic SDFs."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from service.fusion.losses import PhysibleLosses, convexity_loss, hyperplane_loss, support_point_loss
from service.fusion.samples import hyperplane_samples, ray_samples
from service.fusion.types import LossWeights, SampleExtents

TAU = 0.01
R = 0.05


def sphere(p: torch.Tensor, r=R) -> torch.Tensor:
    return p.norm(dim=1) - r


def two_spheres(p: torch.Tensor) -> torch.Tensor:
    """A non-convex body: union of two spheres of radius R centred at ±(1.5 R, 0, 0)."""
    c = torch.tensor([1.5 * R, 0.0, 0.0])
    return torch.minimum((p - c).norm(dim=1), (p + c).norm(dim=1)) - R


def S_np(p, fn=sphere):
    return fn(torch.as_tensor(np.asarray(p), dtype=torch.float32)[None]).item()


def sphere_contacts(n, rng):
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return R * d, d


def t32(a):
    return torch.as_tensor(np.asarray(a), dtype=torch.float32)


def test_support_point_loss_against_naive():
    rng = np.random.default_rng(0)
    x = rng.normal(scale=0.05, size=(50, 3))
    l = rng.normal(scale=0.01, size=50)
    naive = np.mean([((S_np(xi) - li) / TAU) ** 2 for xi, li in zip(x, l)])
    assert support_point_loss(sphere, t32(x), t32(l), TAU).item() == pytest.approx(naive, rel=1e-4)


def test_support_point_loss_zero_on_exact_rays():
    rng = np.random.default_rng(1)
    P, N = sphere_contacts(20, rng)
    x, l = ray_samples(P, N, SampleExtents(), rng)  # S(p + l n) = l exactly for a sphere (l > −R)
    assert support_point_loss(sphere, t32(x), t32(l), TAU).item() < 1e-6
    # a sphere 3 mm too small: every sample is off by 3 mm -> (0.3)² in τ units
    assert support_point_loss(lambda p: sphere(p, R - 0.003), t32(x), t32(l), TAU).item() == pytest.approx(0.09, rel=1e-3)


def test_hyperplane_loss_against_naive_and_one_sided():
    rng = np.random.default_rng(2)
    q = rng.normal(scale=0.05, size=(60, 3))
    b = rng.normal(scale=0.02, size=60)
    naive = np.mean([(min(0.0, S_np(qi) - bi) / TAU) ** 2 for qi, bi in zip(q, b)])
    assert hyperplane_loss(sphere, t32(q), t32(b), TAU).item() == pytest.approx(naive, rel=1e-4)
    # valid lower bounds: supporting planes of the sphere never bind
    P, N = sphere_contacts(10, rng)
    q, b = hyperplane_samples(P, N, SampleExtents(), rng)
    assert hyperplane_loss(sphere, t32(q), t32(b), TAU).item() < 1e-9
    # a sphere 5 mm too large crosses its planes: penalised
    assert hyperplane_loss(lambda p: sphere(p, R + 0.005), t32(q), t32(b), TAU).item() > 1e-3


def convexity_naive(fn, s1, s2, l2, t, eps):
    vals = []
    for a, b, lb, ti in zip(s1, s2, l2, t):
        S1 = S_np(a, fn)
        if abs(S1) > eps:
            continue
        x = ti * a + (1 - ti) * b
        vals.append(max(0.0, S_np(x, fn) - (ti * S1 + (1 - ti) * lb)) / TAU)
    return float(np.mean(vals)) if vals else 0.0


def test_convexity_loss_against_naive():
    rng = np.random.default_rng(3)
    s1 = rng.normal(scale=0.06, size=(80, 3))
    s2 = rng.normal(scale=0.06, size=(80, 3))
    l2 = rng.normal(scale=0.01, size=80)
    t = rng.random(80)
    for fn in (sphere, two_spheres):
        naive = convexity_naive(fn, s1, s2, l2, t, eps=0.02)
        got = convexity_loss(fn, t32(s1), t32(s2), t32(l2), t32(t), TAU, 0.02).item()
        assert got == pytest.approx(naive, rel=1e-4, abs=1e-6)


def test_convexity_zero_for_convex_positive_for_nonconvex():
    rng = np.random.default_rng(4)
    d = rng.normal(size=(400, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    # sphere: s1 on its surface, s2 = exact ray samples
    P, N = sphere_contacts(40, rng)
    x, l = ray_samples(P, N, SampleExtents(), rng)
    i2 = rng.integers(0, len(x), 400)
    t = t32(rng.random(400))
    assert convexity_loss(sphere, t32(R * d), t32(x[i2]), t32(l[i2]), t, TAU, 0.01).item() < 1e-6
    # two spheres: s1 on the left sphere, s2 on the right one: the waist between them violates convexity
    c = np.array([1.5 * R, 0, 0])
    s1 = -c + R * d
    s2 = c + R * d[::-1]
    loss = convexity_loss(two_spheres, t32(s1), t32(s2), t32(np.zeros(400)), t, TAU, 0.01).item()
    assert loss > 0.05


def test_convexity_does_not_train_through_s1():
    """S̄(s₁) is a target: d/dr of the loss with S = |p| − r counts only S(x)."""
    r = torch.nn.Parameter(torch.tensor(R))
    fn = lambda p: p.norm(dim=1) - r  # noqa: E731
    rng = np.random.default_rng(5)
    d = rng.normal(size=(200, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    s1 = t32(R * d)
    s2 = t32(rng.normal(scale=0.1, size=(200, 3)))
    l2 = t32(np.full(200, -0.02))  # a strict bound: most pairs are active
    t = t32(rng.random(200))
    loss = convexity_loss(fn, s1, s2, l2, t, TAU, 0.01)
    loss.backward()
    with torch.no_grad():
        x = t[:, None] * s1 + (1 - t[:, None]) * s2
        active = (fn(x) - (t * fn(s1) + (1 - t) * l2)) > 0
    assert r.grad.item() == pytest.approx(-active.float().mean().item() / TAU, rel=1e-5)


def test_physible_losses_combines_and_is_seeded():
    rng = np.random.default_rng(6)
    P, N = sphere_contacts(10, rng)
    x, l = ray_samples(P, N, SampleExtents(), rng)
    q, b = hyperplane_samples(P, N, SampleExtents(), rng)
    d = rng.normal(size=(300, 3))
    s_vis = R * d / np.linalg.norm(d, axis=1, keepdims=True)
    w = LossWeights(n_sp=100, n_hc=200, n_cvx=150)
    small = lambda p: sphere(p, R - 0.004)  # noqa: E731
    a = PhysibleLosses(x, l, q, b, s_vis, w, TAU, seed=3)
    b2 = PhysibleLosses(x, l, q, b, s_vis, w, TAU, seed=3)
    va, vb = a(small, 0).item(), b2(small, 0).item()
    assert va == vb
    assert va == pytest.approx(w.sp * a.last["sp"] + w.hc * a.last["hc"] + w.cvx * a.last["cvx"], rel=1e-5)
    assert a.last["sp"] == pytest.approx(0.16, rel=1e-3)  # 4 mm everywhere on the rays
    assert a.last["hc"] == 0.0  # a smaller sphere never crosses the planes
    assert PhysibleLosses(x, l, q, b, s_vis, w, TAU)(sphere, 0).item() < 1e-6
    empty = PhysibleLosses(np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)), np.zeros(0), s_vis, w, TAU)
    assert empty(small, 0).item() == 0.0


def test_physible_losses_parts_equal_the_pure_functions():
    """The fused single-query path gives the same terms as the separate pure functions."""
    rng = np.random.default_rng(7)
    P, N = sphere_contacts(3, rng)
    ext = SampleExtents(ray_n_in=10, ray_n_out=10, ray_n_far=5, hc_n_in=10, hc_n_near=5, hc_n_far=5)
    x, l = ray_samples(P, N, ext, rng)
    q, b = hyperplane_samples(P, N, ext, rng)
    d = rng.normal(size=(50, 3))
    s_vis = R * d / np.linalg.norm(d, axis=1, keepdims=True)
    w = LossWeights(n_sp=1000, n_hc=1000, n_cvx=300)  # pools smaller than n: sp/hc use every sample
    fn = lambda p: two_spheres(p * 1.3)  # noqa: E731  (non-convex, nothing exactly zero)
    losses = PhysibleLosses(x, l, q, b, s_vis, w, TAU, seed=11)
    losses(fn, 0)
    assert losses.last["sp"] == pytest.approx(support_point_loss(fn, t32(x), t32(l), TAU).item(), rel=1e-5)
    assert losses.last["hc"] == pytest.approx(hyperplane_loss(fn, t32(q), t32(b), TAU).item(), rel=1e-5)
    g = torch.Generator().manual_seed(11)
    i1 = torch.randint(0, len(s_vis), (300,), generator=g)
    i2 = torch.randint(0, len(x), (300,), generator=g)
    t = torch.rand(300, generator=g)
    ref = convexity_loss(fn, t32(s_vis)[i1], t32(x)[i2], t32(l)[i2], t, TAU, w.eps_cvx).item()
    assert ref > 0 and losses.last["cvx"] == pytest.approx(ref, rel=1e-5)
