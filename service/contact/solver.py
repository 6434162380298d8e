"""Batched solver of convex quadratic programs over products of Lorentz (second-order) cones.

Problem, one per batch element b (solved for all b at once, no gradient):

    min_x  ½ xᵀ P x + qᵀ x    s.t.  x_i = (x_i,n, x_i,t1, x_i,t2) ∈ K = {(n, t): ‖t‖₂ ≤ n}, i = 1..n_c

P (B,3n_c,3n_c) symmetric positive semi-definite (possibly rank deficient), q (B,3n_c).
Layout: contact i owns the three consecutive rows 3i (normal), 3i+1, 3i+2 (tangential).

Method: ADMM on the splitting x = z, z ∈ K (Boyd et al., "Distributed optimization ... ADMM", 2011;
O'Donoghue et al., SCS 2016, for the cone projection):

    x ← (P + ρI)⁻¹ (ρ (z − u) − q)
    x̂ ← α x + (1 − α) z                       (over-relaxation, α = 1.6)
    z ← Π_K(x̂ + u)
    u ← u + x̂ − z

with a per-cone diagonal scaling (cones are invariant under positive scaling), a per-instance step ρ,
adapted every ``check_every`` iterations from the ratio of primal and dual residuals (OSQP rule), and
a batch-wide stop when every instance meets ‖x − z‖∞ ≤ eps_abs + eps_rel·‖z‖∞ and the dual residual
likewise. The inverse (P + ρI)⁻¹ is formed once per ρ (3n_c ≤ ~30, so a batched inverse is cheapest).

Projection onto K: (n, t) stays if ‖t‖ ≤ n; → 0 if ‖t‖ ≤ −n; else a(1, t/‖t‖) with a = (n + ‖t‖)/2.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class SolverSettings:
    max_iters: int = 200
    check_every: int = 10
    eps_abs: float = 1e-8
    eps_rel: float = 1e-5
    alpha: float = 1.6
    adapt_rho: bool = True
    rho0: float = 1.0
    norm_floor: float = 1e-2  # see the ρ adaptation


@dataclass
class SolverResult:
    x: torch.Tensor  # (B,3n_c) solution (projected onto the cones)
    iters: int
    primal_residual: torch.Tensor  # (B,)
    dual_residual: torch.Tensor  # (B,)


def project_lorentz(v: torch.Tensor) -> torch.Tensor:
    """Project (…,3) vectors [n, t1, t2] onto the cone ‖t‖ ≤ n."""
    n = v[..., :1]
    t = v[..., 1:]
    tn = torch.linalg.vector_norm(t, dim=-1, keepdim=True)
    a = (0.5 * (n + tn)).clamp_min(0.0)
    inside = tn <= n
    n_out = torch.where(inside, n, a)
    s = torch.where(inside, torch.ones_like(a), a / (tn + 1e-300))
    return torch.cat([n_out, t * s], -1)


def objective(P: torch.Tensor, q: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """½ xᵀPx + qᵀx per batch element, (B,)."""
    return 0.5 * torch.einsum("bi,bij,bj->b", x, P, x) + (q * x).sum(-1)


@torch.no_grad()
def solve_cone_qp(
    P: torch.Tensor,
    q: torch.Tensor,
    settings: SolverSettings = SolverSettings(),
    x0: torch.Tensor | None = None,
) -> SolverResult:
    """Solve the batch of cone QPs described in the module docstring. Returns x (B,3n_c)."""
    B, n = q.shape
    nc = n // 3
    if nc * 3 != n or P.shape != (B, n, n):
        raise ValueError(f"P must be (B,3nc,3nc) and q (B,3nc); got {tuple(P.shape)} and {tuple(q.shape)}")
    dtype = q.dtype
    P = P.detach()
    q = q.detach()
    if B == 0:
        z = torch.zeros_like(q)
        return SolverResult(z, 0, z.sum(-1), z.sum(-1))
    # per-cone scaling x = D x̃, D = diag(d_i) constant over each cone's 3 rows
    diag = torch.diagonal(P, dim1=-2, dim2=-1).reshape(B, nc, 3).mean(-1)  # (B,nc)
    ref = diag.mean(-1, keepdim=True).clamp_min(1e-12)
    d = torch.rsqrt(diag.clamp_min(1e-6 * ref))  # (B,nc)
    d3 = d.repeat_interleave(3, dim=1)  # (B,n)
    Ps = P * d3.unsqueeze(-1) * d3.unsqueeze(-2)
    qs = q * d3
    # cost scaling so that typical entries are O(1)
    c = 1.0 / torch.maximum(torch.diagonal(Ps, dim1=-2, dim2=-1).mean(-1), qs.abs().amax(-1)).clamp_min(1e-12)
    Ps = Ps * c.view(B, 1, 1)
    qs = qs * c.view(B, 1)
    eye = torch.eye(n, dtype=dtype)
    if x0 is not None:
        z = project_lorentz((x0.detach() / d3).reshape(B, nc, 3)).reshape(B, n)
    else:
        z = torch.zeros(B, n, dtype=dtype)
    # λ = 0 is optimal when q lies in the (self-dual) cone K: those instances need no iterations
    qc = qs.reshape(B, nc, 3)
    trivial = (qc[..., 0] >= torch.linalg.vector_norm(qc[..., 1:], dim=-1)).all(-1)
    z = torch.where(trivial.view(B, 1), torch.zeros_like(z), z)
    active = (~trivial).nonzero().squeeze(-1)
    r_prim = torch.zeros(B, dtype=dtype)
    r_dual = torch.zeros(B, dtype=dtype)
    Z = z.clone()
    # work on the active (unconverged) instances only; converged ones are written back to Z
    Pa, qa, za = Ps[active], qs[active], z[active]
    Ba = len(active)
    rho = torch.full((Ba,), settings.rho0, dtype=dtype)
    Kinv = torch.linalg.inv(Pa + rho.view(Ba, 1, 1) * eye)
    ua = torch.zeros(Ba, n, dtype=dtype)
    a = settings.alpha
    it = 0
    while it < settings.max_iters and Ba > 0:
        for _ in range(settings.check_every):
            rhs = rho.view(Ba, 1) * (za - ua) - qa
            x = torch.bmm(Kinv, rhs.unsqueeze(-1)).squeeze(-1)
            xh = a * x + (1.0 - a) * za
            z_old = za
            za = project_lorentz((xh + ua).reshape(Ba, nc, 3)).reshape(Ba, n)
            ua = ua + xh - za
        it += settings.check_every
        rp = (x - za).abs().amax(-1)
        rd = (rho.view(Ba, 1) * (za - z_old)).abs().amax(-1)
        zn = za.abs().amax(-1)
        Px = torch.bmm(Pa, x.unsqueeze(-1)).squeeze(-1)
        dn = torch.maximum(Px.abs().amax(-1), qa.abs().amax(-1))
        done = (rp <= settings.eps_abs + settings.eps_rel * zn) & (rd <= settings.eps_abs + settings.eps_rel * dn)
        Z[active] = za
        r_prim[active] = rp
        r_dual[active] = rd
        if bool(done.all()) or it >= settings.max_iters:
            break
        keep = ~done
        active, Pa, qa, za, ua, rho, Kinv = active[keep], Pa[keep], qa[keep], za[keep], ua[keep], rho[keep], Kinv[keep]
        rp, rd, zn = rp[keep], rd[keep], zn[keep]
        Ba = len(active)
        if settings.adapt_rho:
            # OSQP rule. The dual residual is normalised by ‖y‖ (y = ρu), as long as y is not negligible against
            # max(‖Px‖, ‖q‖): with y = 0 (z still inside the cones, e.g. resting contacts) ‖y‖ alone drove ρ back
            # and forth between its bounds and the solver returned λ = 0. The same guard for ‖z‖ vs ‖x‖.
            fl = settings.norm_floor
            dnorm = torch.maximum(rho * ua.abs().amax(-1), fl * dn[keep]).clamp_min(1e-30)
            pnorm = torch.maximum(zn, fl * x[keep].abs().amax(-1)).clamp_min(1e-30)
            ratio = torch.sqrt((rp / pnorm) / (rd / dnorm + 1e-30) + 1e-30)
            new_rho = (rho * ratio).clamp(1e-6, 1e6)
            change = (new_rho > 5 * rho) | (new_rho < rho / 5)
            if bool(change.any()):
                # the scaled dual u = y/ρ is rescaled when ρ changes
                ua = torch.where(change.view(Ba, 1), ua * (rho / new_rho).view(Ba, 1), ua)
                rho = torch.where(change, new_rho, rho)
                Kinv = torch.linalg.inv(Pa + rho.view(Ba, 1, 1) * eye)
    z = Z
    return SolverResult(z * d3, it, r_prim, r_dual)
