"""The batched cone-QP solver against an independent interior-point solver (Clarabel) and SLSQP."""

import numpy as np
import pytest
import torch
from scipy.optimize import minimize

from service.contact.solver import SolverSettings, objective, project_lorentz, solve_cone_qp


def _instances(rng, B, nc, rank):
    n = 3 * nc
    G = rng.normal(size=(B, n, rank))
    P = G @ G.transpose(0, 2, 1)
    a = rng.normal(size=(B, n))
    c = np.zeros((B, nc, 3))
    c[..., 0] = rng.uniform(0.1, 1, (B, nc))
    c[..., 1:] = rng.normal(size=(B, nc, 2)) * 0.05
    q = -np.einsum("bij,bj->bi", P, a) + c.reshape(B, n)  # bounded: q·x ≥ 0 on K ∩ null(P)
    return P, q


def test_projection_is_the_euclidean_projection():
    g = torch.Generator().manual_seed(0)
    v = torch.randn(2000, 3, generator=g, dtype=torch.float64) * 2
    p = project_lorentz(v)
    # feasible, idempotent, Moreau: v = Π_K(v) − Π_K(−v) with Π_K(v) ⟂ Π_K(−v)
    assert (p[:, 0] >= p[:, 1:].norm(dim=-1) - 1e-12).all()
    assert torch.allclose(project_lorentz(p), p, atol=1e-12)
    m = project_lorentz(-v)
    assert torch.allclose(p - m, v, atol=1e-10)
    assert (p * m).sum(-1).abs().max() < 1e-9


def test_matches_slsqp_single_cone_strictly_convex():
    rng = np.random.default_rng(1)
    P, q = _instances(rng, 12, 1, 3)
    P = P + 0.1 * np.eye(3)
    res = solve_cone_qp(torch.tensor(P), torch.tensor(q), SolverSettings(max_iters=2000, eps_rel=1e-9, eps_abs=1e-12))
    for b in range(12):
        cons = [{"type": "ineq", "fun": lambda x: x[0] - np.sqrt(x[1] ** 2 + x[2] ** 2 + 1e-16)}]
        r = minimize(lambda x: 0.5 * x @ P[b] @ x + q[b] @ x, np.array([1.0, 0, 0]), jac=lambda x: P[b] @ x + q[b],
                     constraints=cons, method="SLSQP", options={"ftol": 1e-14, "maxiter": 500})
        f_ref = min(r.fun, 0.0)  # x = 0 is feasible
        f = float(objective(torch.tensor(P[b : b + 1]), torch.tensor(q[b : b + 1]), res.x[b : b + 1]))
        assert f <= f_ref + 1e-6 * (1 + abs(f_ref))
        assert f >= f_ref - 1e-4 * (1 + abs(f_ref))  # SLSQP is the less accurate of the two


@pytest.mark.parametrize("nc,rank", [(1, 3), (3, 6), (6, 6), (6, 3)])
def test_matches_clarabel(nc, rank):
    clarabel = pytest.importorskip("clarabel")  # test extra: independent interior-point SOCP solver
    import scipy.sparse as sp

    rng = np.random.default_rng(nc * 10 + rank)
    B, n = 12, 3 * nc
    P, q = _instances(rng, B, nc, rank)
    res = solve_cone_qp(torch.tensor(P), torch.tensor(q), SolverSettings(max_iters=3000, eps_rel=1e-8, eps_abs=1e-11))
    f = objective(torch.tensor(P), torch.tensor(q), res.x).numpy()
    x = res.x.numpy().reshape(B, nc, 3)
    assert (x[..., 0] >= np.linalg.norm(x[..., 1:], axis=-1) - 1e-9).all()
    for b in range(B):
        st = clarabel.DefaultSettings()
        st.verbose = False
        s = clarabel.DefaultSolver(sp.csc_matrix(np.triu(P[b])), q[b], sp.csc_matrix(-np.eye(n)), np.zeros(n),
                                   [clarabel.SecondOrderConeT(3)] * nc, st)
        r = s.solve()
        scale = 1 + abs(r.obj_val)
        assert abs(f[b] - r.obj_val) <= 1e-4 * scale, (b, f[b], r.obj_val)


def test_zero_when_q_in_cone_and_warm_start_consistent():
    rng = np.random.default_rng(3)
    P, q = _instances(rng, 10, 4, 6)
    qc = np.abs(q.reshape(10, 4, 3))
    qc[..., 0] = 2 + np.linalg.norm(qc[..., 1:], axis=-1)
    r0 = solve_cone_qp(torch.tensor(P), torch.tensor(qc.reshape(10, 12)))
    assert r0.x.abs().max() == 0
    a = solve_cone_qp(torch.tensor(P), torch.tensor(q), SolverSettings(max_iters=1000, eps_rel=1e-8))
    b = solve_cone_qp(torch.tensor(P), torch.tensor(q), SolverSettings(max_iters=1000, eps_rel=1e-8), x0=a.x)
    fa = objective(torch.tensor(P), torch.tensor(q), a.x)
    fb = objective(torch.tensor(P), torch.tensor(q), b.x)
    assert torch.allclose(fa, fb, atol=1e-6)
    assert b.iters <= a.iters



def test_resting_cube_transition_gets_its_resting_impulse():
    """A recorded resting transition of the real cube (148 Hz) with a sharp 0.1024 m cube as geometry: two of
    the five table witnesses coincide (one corner answers two query directions), P is rank deficient and the
    optimum lies inside the cones. The ρ adaptation once normalised the dual residual by ‖y‖ alone; with y = 0
    it drove ρ back and forth between its bounds and returned λ = 0 (objective 0 instead of about −3.1e-3)."""
    from service.contact.learn import ContactModel, LossWeights, Transitions, contact_loss

    class Corners(torch.nn.Module):  # support points of a sharp cube
        def forward(self, d):
            return 0.0512 * torch.sign(d)

    nu = [0.004916777747260703, -0.006543789229817655, -0.004942621239412738, 0.0003547433346071733,
          6.415484030188645e-05, -9.15026699757304e-05]
    quat = [0.5373357310807455, 0.46031997730578733, 0.5348519969884205, -0.46185405910808996]
    p = [-0.15094944208053276, 0.10553677371908853, 0.05105045533014676]
    nu1 = [-0.0005918089997890448, -5.3230914558018255e-05, -9.396704723002778e-05, 0.0008654677539103186,
           0.00011969775800154427, -9.15026699757304e-05]
    t = lambda a: torch.tensor([a], dtype=torch.float64)  # noqa: E731
    tr = Transitions(np.zeros(1), np.zeros(1), t(nu), t(quat), t(p), t(nu1), None, None)
    m = 0.37
    model = ContactModel(8, 0.1, m, np.zeros(3), m * 0.1048**2 / 6 * np.eye(3), 0.26, 0.15)
    model.geometry = Corners()
    with torch.no_grad():
        res = contact_loss(model, tr, 1 / 148, LossWeights(pen=50.0), 5, torch.Generator().manual_seed(1),
                           SolverSettings(max_iters=100, eps_rel=1e-4))
    # the observed vertical velocity change (resting: gravity cancelled) is explained by the impulses
    assert abs(float(res.dv_explained[0, 5]) - float(res.dv_observed[0, 5])) < 0.1 * abs(float(res.dv_observed[0, 5]))
    assert res.terms["pred"] < 0.05 * 0.5 * m * float(res.dv_observed[0, 5]) ** 2
