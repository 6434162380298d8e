"""Contact-implicit learning of convex geometry and inertia: the PLL / ContactNets violation-implicit loss.

For a transition (x_k, x_{k+1}) everything is evaluated at the next state q⁺ (method-notes §2.1–2.4):
M = M(q⁺), F = F(q⁺, ν⁺), MΔv = M(ν⁺ − ν) − dt F, contacts i = 1..n_c (end-effector sphere first if a robot
is present, then ``n_plane`` table candidates) with gaps φ_i, Jacobian J (3n_c × 6, rows [n_i; μ t_i,1; μ t_i,2],
μ folded in), sliding velocities s_i = μ T_iᵀ(J_p,i ν⁺ − v_E). With λ ∈ Π Lorentz cones:

    L_pred(λ) = ½ (MΔv − Jᵀλ)ᵀ M⁻¹ (MΔv − Jᵀλ)
    L_comp(λ) = Σ λ_n,i max(φ_i, 0)
    L_diss(λ) = dt Σ (λ_n,i ‖s_i‖ + λ_t,iᵀ s_i)
    L_pen     = Σ max(−φ_i, 0)²
    λ* = argmin_{λ∈K} w_pred L_pred + w_comp L_comp + w_diss L_diss      (convex cone QP, no gradient)
    L_CN = w_pred L_pred(λ*) + w_comp L_comp(λ*) + w_diss L_diss(λ*) + w_pen L_pen

``LossWeights.pen_ee`` (``ContactConfig.w_pen_ee``), when set, weighs the sphere contact's term of L_pen instead of
w_pen (the sphere's position is measured by the robot; docs/contact.md, strike sessions).

By the envelope theorem dL_CN/dθ = ∂L_CN/∂θ at fixed λ*, so λ* is detached. Samples with |λ*| > 1e3 or
non-finite λ* are dropped (PLL). Vision term (§6.1): L_vis = mean_v |n̂ᵥ·(s(n̂ᵥ) − sᵥ)| with n̂ᵥ the outward
direction from the closest point of the (detached) exported hull to sᵥ. Total: mean_batch L_CN + w_vis L_vis.
Adam (lr 2e-3 in PLL), batches of transitions, the parameters of the best epoch are kept.

Table witness candidates (§3.2): d₀ = −Rᵀe_z and n_plane − 1 directions on a cone around d₀ with cos θ ~ U[0.5,1]
and a random azimuth offset; φ_j = e_z·(R s(d_j) + p) − z_table. Sphere (§3.3): closest point p' of the
detached hull to the sphere centre c (O frame), n = unit(p' − c) (flipped if c is inside), object witness
s(−n), φ = n_W·(R s + p − p_E) − r.

Physible set (§6.2): all (witness point, outward direction) pairs whose normal impulse exceeds the
(1 − physible_fraction)-quantile of all normal impulses of all contacts of all transitions.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import nn

from service.contact import dynamics as dyn
from service.contact.geometry import (
    HomogeneousICNN,
    PolytopeSupport,
    cube_surface_directions,
    export_mesh,
    fibonacci_directions,
    hull_mesh,
    outward_directions_to,
    pretrain_to_points,
)
from service.contact.inertia import RigidBodyInertia, solid_hull_inertia
from service.contact.solver import SolverSettings, solve_cone_qp
from service.mesh import Mesh


@dataclass(frozen=True)
class LossWeights:
    pred: float = 4.0
    comp: float = 1.0
    diss: float = 5000.0
    pen: float = 0.5
    vision: float = 0.04
    pen_ee: float | None = None  # penetration weight of the sphere contact (None: ``pen``)


@dataclass
class Transitions:
    """Flattened transitions (S = number of transitions), torch float64."""

    traj: np.ndarray  # (S,)
    step: np.ndarray  # (S,)
    nu: torch.Tensor  # (S,6) [ω body; v world] at k
    quat_next: torch.Tensor  # (S,4) at k+1
    p_next: torch.Tensor  # (S,3)
    nu_next: torch.Tensor  # (S,6)
    ee_p: torch.Tensor | None  # (S,3) sphere centre at k+1
    ee_v: torch.Tensor | None  # (S,3)

    def __len__(self) -> int:
        return len(self.traj)

    def take(self, idx) -> "Transitions":
        i = torch.as_tensor(idx, dtype=torch.long)
        return Transitions(
            self.traj[np.asarray(idx)], self.step[np.asarray(idx)], self.nu[i], self.quat_next[i], self.p_next[i],
            self.nu_next[i], None if self.ee_p is None else self.ee_p[i], None if self.ee_v is None else self.ee_v[i],
        )


def make_transitions(states, ee_p=None, ee_v=None, table_height: float = 0.0) -> Transitions:
    """Transitions of trajectories ``states`` (list of (T,13)); heights are shifted so the table is z = 0."""
    tr, st, nu, qn, pn, nun, ep, ev = [], [], [], [], [], [], [], []
    for k, X in enumerate(states):
        X = np.asarray(X, float)
        T = len(X)
        if T < 2:
            continue
        tr.append(np.full(T - 1, k))
        st.append(np.arange(T - 1))
        nu.append(X[:-1, 7:13])
        qn.append(X[1:, 0:4])
        p = X[1:, 4:7].copy()
        p[:, 2] -= table_height
        pn.append(p)
        nun.append(X[1:, 7:13])
        if ee_p is not None:
            e = np.asarray(ee_p[k], float)[1:].copy()
            e[:, 2] -= table_height
            ep.append(e)
            ev.append(np.asarray(ee_v[k], float)[1:])
    t = lambda a: torch.as_tensor(np.concatenate(a), dtype=torch.float64)  # noqa: E731
    return Transitions(
        np.concatenate(tr), np.concatenate(st), t(nu), t(qn), t(pn), t(nun),
        t(ep) if ee_p is not None else None, t(ev) if ee_p is not None else None,
    )


class ContactModel(nn.Module):
    """Learnable geometry (deep support function), inertia and (optionally) friction."""

    def __init__(self, width: int, length_scale: float, mass: float, com, inertia, mu_table: float, mu_robot: float,
                 *, learn_com: bool = True, learn_friction: bool = False, learn_mass: bool = False,
                 generator: torch.Generator | None = None, geometry: nn.Module | None = None):
        super().__init__()
        self.geometry = geometry if geometry is not None else HomogeneousICNN(width, length_scale, generator)
        self.inertia = RigidBodyInertia(mass, com, inertia, learn_com=learn_com, learn_mass=learn_mass)
        lmu = torch.log(torch.tensor([mu_table, mu_robot], dtype=torch.float64))
        self.log_mu = nn.Parameter(lmu, requires_grad=learn_friction)

    @property
    def mu(self) -> torch.Tensor:
        return torch.exp(self.log_mu)


def _tangents(n: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Orthonormal tangents (…,3) to unit normals n (…,3)."""
    a = torch.where((n[..., 0].abs() < 0.9).unsqueeze(-1), torch.tensor([1.0, 0, 0], dtype=n.dtype),
                    torch.tensor([0, 1.0, 0], dtype=n.dtype)).expand_as(n)
    t1 = torch.cross(n, a, dim=-1)
    t1 = t1 / t1.norm(dim=-1, keepdim=True)
    return t1, torch.cross(n, t1, dim=-1)


def plane_directions(R: torch.Tensor, n_plane: int, gen: torch.Generator) -> torch.Tensor:
    """(B,n_plane,3) query directions in O: d₀ = −Rᵀe_z and a ring on a cone with cos θ ~ U[0.5,1]."""
    B = R.shape[0]
    d0 = -R[:, 2, :]  # −Rᵀ e_z (row 3 of R)
    if n_plane <= 1:
        return d0.unsqueeze(1)
    e1, e2 = _tangents(d0)
    cos_t = 0.5 + 0.5 * torch.rand(B, 1, dtype=R.dtype, generator=gen)
    sin_t = torch.sqrt(1 - cos_t**2)
    off = 2 * math.pi * torch.rand(B, 1, dtype=R.dtype, generator=gen)
    az = off + 2 * math.pi * torch.arange(n_plane - 1, dtype=R.dtype) / (n_plane - 1)
    ring = (cos_t.unsqueeze(-1) * d0.unsqueeze(1)
            + sin_t.unsqueeze(-1) * (torch.cos(az).unsqueeze(-1) * e1.unsqueeze(1) + torch.sin(az).unsqueeze(-1) * e2.unsqueeze(1)))
    return torch.cat([d0.unsqueeze(1), ring], 1)


def sphere_centres_O(R: torch.Tensor, p: torch.Tensor, ee_p: torch.Tensor) -> np.ndarray:
    """Sphere centres in O, (B,3) numpy (data only: independent of the learned parameters)."""
    return (R.transpose(-1, -2) @ (ee_p - p).unsqueeze(-1)).squeeze(-1).detach().numpy()


def sphere_directions(hull: Mesh, R: torch.Tensor, p: torch.Tensor, ee_p: torch.Tensor) -> torch.Tensor:
    """(B,3) unit outward directions from the closest points of the detached hull to the sphere centres (O)."""
    _, _, nout = outward_directions_to(hull, sphere_centres_O(R, p, ee_p))
    return torch.as_tensor(nout, dtype=R.dtype)


@dataclass
class ContactSet:
    phi: torch.Tensor  # (B,nc)
    J: torch.Tensor  # (B,3nc,6), rows per contact [n, μt1, μt2]
    slide: torch.Tensor  # (B,nc,2) μ Tᵀ(relative witness velocity at ν⁺)
    witness_O: torch.Tensor  # (B,nc,3) object witness points in O
    normal_O: torch.Tensor  # (B,nc,3) outward object direction in O (= −contact normal)
    is_ee: torch.Tensor  # (nc,) bool


def contact_set(model: ContactModel, R: torch.Tensor, p: torch.Tensor, nu_next: torch.Tensor, n_plane: int,
                gen: torch.Generator, ee_p: torch.Tensor | None = None, ee_v: torch.Tensor | None = None,
                ee_radius: float = 0.0, hull: Mesh | None = None, ee_dirs: torch.Tensor | None = None) -> ContactSet:
    """Contacts at the next state (table at z = 0). ``ee_dirs`` (B,3): outward hull directions toward the sphere
    centres, precomputed on a detached hull (else computed here from ``hull``)."""
    B = R.shape[0]
    mu = model.mu
    ez = torch.tensor([0.0, 0.0, 1.0], dtype=R.dtype)
    dirs = plane_directions(R, n_plane, gen)  # (B,k,3)
    s = model.geometry(dirs)  # (B,k,3)
    w = (R.unsqueeze(1) @ s.unsqueeze(-1)).squeeze(-1) + p.unsqueeze(1)
    phi = w[..., 2]
    Rb = R.unsqueeze(1)
    ex = torch.tensor([1.0, 0.0, 0.0], dtype=R.dtype)
    ey = torch.tensor([0.0, 1.0, 0.0], dtype=R.dtype)
    rows = [dyn.direction_rows(Rb, s, u.expand_as(s)) for u in (ez, ex, ey)]  # each (B,k,6)
    Jn, Jx, Jy = rows
    Jp = torch.stack([Jn, mu[0] * Jx, mu[0] * Jy], 2)  # (B,k,3,6)
    slide = torch.stack([(mu[0] * Jx * nu_next.unsqueeze(1)).sum(-1), (mu[0] * Jy * nu_next.unsqueeze(1)).sum(-1)], -1)
    normal_O = dirs[:, :1, :].expand_as(dirs)  # PLL: all table witnesses share −table normal in O
    parts_phi, parts_J, parts_sl, parts_w, parts_n = [phi], [Jp], [slide], [s], [normal_O]
    is_ee = [False] * dirs.shape[1]
    if ee_p is not None:
        # n̂ is the outward object normal toward the sphere centre; contact normal (sphere -> object) = −n̂
        dq = ee_dirs if ee_dirs is not None else sphere_directions(hull, R, p, ee_p)
        se = model.geometry(dq)  # (B,3)
        nW = -(R @ dq.unsqueeze(-1)).squeeze(-1)
        we = (R @ se.unsqueeze(-1)).squeeze(-1) + p
        phie = (nW * (we - ee_p)).sum(-1) - ee_radius
        t1, t2 = _tangents(nW)
        rn = dyn.direction_rows(R, se, nW)
        r1 = dyn.direction_rows(R, se, t1)
        r2 = dyn.direction_rows(R, se, t2)
        Je = torch.stack([rn, mu[1] * r1, mu[1] * r2], 1).unsqueeze(1)  # (B,1,3,6)
        rel1 = (r1 * nu_next).sum(-1) - (t1 * ee_v).sum(-1)
        rel2 = (r2 * nu_next).sum(-1) - (t2 * ee_v).sum(-1)
        sle = mu[1] * torch.stack([rel1, rel2], -1).unsqueeze(1)
        parts_phi.insert(0, phie.unsqueeze(1))
        parts_J.insert(0, Je)
        parts_sl.insert(0, sle)
        parts_w.insert(0, se.unsqueeze(1))
        parts_n.insert(0, dq.unsqueeze(1))
        is_ee = [True] + is_ee
    J = torch.cat(parts_J, 1)
    nc = J.shape[1]
    return ContactSet(torch.cat(parts_phi, 1), J.reshape(B, 3 * nc, 6), torch.cat(parts_sl, 1),
                      torch.cat(parts_w, 1), torch.cat(parts_n, 1), torch.tensor(is_ee))


@dataclass
class BatchResult:
    loss: torch.Tensor  # scalar, mean over valid samples of L_CN
    per_sample: torch.Tensor  # (B,)
    lam: torch.Tensor  # (B,3nc)
    valid: torch.Tensor  # (B,)
    contacts: ContactSet
    dv_observed: torch.Tensor  # (B,6) ν⁺ − ν − dt M⁻¹F
    dv_explained: torch.Tensor  # (B,6) M⁻¹Jᵀλ*
    terms: dict = field(default_factory=dict)
    solver_time: float = 0.0
    solver_iters: int = 0


def contact_loss(model: ContactModel, batch: Transitions, dt: float, w: LossWeights, n_plane: int,
                 gen: torch.Generator, solver: SolverSettings, ee_radius: float = 0.0, hull: Mesh | None = None,
                 lam0: torch.Tensor | None = None, ee_dirs: torch.Tensor | None = None) -> BatchResult:
    """The violation-implicit loss of a batch of transitions (module docstring)."""
    R = dyn.quat_to_mat(batch.quat_next)
    m = model.inertia.mass
    c = model.inertia.com
    Ic = model.inertia.central_inertia()
    M = dyn.mass_matrix(R, m, c, Ic)
    F = dyn.bias_force(R, batch.nu_next, m, c, Ic)
    Mdv = (M @ (batch.nu_next - batch.nu).unsqueeze(-1)).squeeze(-1) - dt * F
    Lc = torch.linalg.cholesky(M)
    cs = contact_set(model, R, batch.p_next, batch.nu_next, n_plane, gen, batch.ee_p, batch.ee_v, ee_radius, hull,
                     ee_dirs)
    B, n3, _ = cs.J.shape
    nc = n3 // 3
    X = torch.linalg.solve_triangular(Lc, cs.J.transpose(-1, -2), upper=False)  # L⁻¹Jᵀ (B,6,3nc)
    b = torch.linalg.solve_triangular(Lc, Mdv.unsqueeze(-1), upper=False).squeeze(-1)  # L⁻¹MΔv
    sn = torch.sqrt((cs.slide**2).sum(-1) + 1e-20)  # (B,nc)
    lin_c = torch.stack([w.comp * cs.phi.clamp_min(0) + w.diss * dt * sn, w.diss * dt * cs.slide[..., 0],
                         w.diss * dt * cs.slide[..., 1]], -1).reshape(B, n3)
    with torch.no_grad():
        Pq = w.pred * X.transpose(-1, -2) @ X
        qq = -w.pred * (X.transpose(-1, -2) @ b.unsqueeze(-1)).squeeze(-1) + lin_c
        t0 = time.perf_counter()
        res = solve_cone_qp(Pq, qq, solver, x0=lam0)
        st = time.perf_counter() - t0
        lam = res.x
        valid = torch.isfinite(lam).all(-1) & (lam.abs().amax(-1) <= 1e3)
        lam = torch.where(valid.unsqueeze(-1), lam, torch.zeros_like(lam))
    lam3 = lam.reshape(B, nc, 3)
    resid = b - (X @ lam.unsqueeze(-1)).squeeze(-1)
    L_pred = 0.5 * (resid**2).sum(-1)
    L_comp = (lam3[..., 0] * cs.phi.clamp_min(0)).sum(-1)
    L_diss = dt * (lam3[..., 0] * sn + (lam3[..., 1:] * cs.slide).sum(-1)).sum(-1)
    pen_c = cs.phi.clamp_max(0) ** 2  # (B,nc)
    L_pen = pen_c.sum(-1)
    if w.pen_ee is None or not bool(cs.is_ee.any()):
        L_pen_w = w.pen * L_pen
    else:
        wc = torch.where(cs.is_ee, torch.tensor(float(w.pen_ee), dtype=pen_c.dtype), torch.tensor(float(w.pen), dtype=pen_c.dtype))
        L_pen_w = (pen_c * wc).sum(-1)
    per = w.pred * L_pred + w.comp * L_comp + w.diss * L_diss + L_pen_w
    per = torch.where(valid, per, torch.zeros_like(per))
    loss = per.sum() / valid.sum().clamp_min(1)
    with torch.no_grad():
        dv_obs = batch.nu_next - batch.nu - dt * torch.linalg.solve(M, F.unsqueeze(-1)).squeeze(-1)
        dv_exp = torch.linalg.solve(M, (cs.J.transpose(-1, -2) @ lam.unsqueeze(-1))).squeeze(-1)
    terms = {k: float(v.detach().mean()) for k, v in (("pred", L_pred), ("comp", L_comp), ("diss", L_diss),
                                                     ("pen", L_pen))}
    return BatchResult(loss, per.detach(), lam, valid, cs, dv_obs, dv_exp, terms, st, res.iters)


def vision_directions(hull: Mesh, V: torch.Tensor, candidates: int = 0) -> torch.Tensor:
    """(K,3) outward directions n̂ᵥ from the closest points of the detached hull to the visible points V (K,3)."""
    _, _, n = outward_directions_to(hull, V.numpy(), candidates)
    return torch.as_tensor(n, dtype=torch.float64)


def vision_loss(model: ContactModel, V: torch.Tensor, hull: Mesh | None, nt: torch.Tensor | None = None) -> torch.Tensor:
    """mean_v |n̂ᵥ·(s(n̂ᵥ) − sᵥ)| (method-notes §6.1), hull detached; ``nt`` = precomputed n̂ᵥ (K,3)."""
    if nt is None:
        nt = vision_directions(hull, V)
    sp = model.geometry(nt)
    return ((sp - V) * nt).sum(-1).abs().mean()


def init_geometry(model: ContactModel, init_vertices: np.ndarray | None, init_radius: float, steps: int) -> None:
    """Pre-fit the support function to the initial guess (hull of init vertices, else a ball)."""
    if steps <= 0:
        return
    if init_vertices is not None:
        verts = np.asarray(init_vertices, float)
        try:  # only the hull vertices matter for support points (a visible mesh has thousands of vertices)
            from scipy.spatial import ConvexHull

            verts = verts[ConvexHull(verts).vertices]
        except Exception:  # degenerate (flat) guesses: keep all points
            pass
    else:
        verts = init_radius * fibonacci_directions(400)
    pretrain_to_points(model.geometry, verts, steps=steps)


def polytope_init(init_vertices: np.ndarray | None, init_radius: float, n_vertices: int) -> np.ndarray:
    """(N,3) initial vertices: the support points of the guess (hull of init vertices, else the ball of radius
    ``init_radius``) in ``n_vertices`` nearly uniform directions."""
    d = fibonacci_directions(n_vertices)
    if init_vertices is None:
        return init_radius * d
    V = np.asarray(init_vertices, float)
    return V[np.argmax(d @ V.T, -1)]


def build_model(mass: float, mu_table: float, mu_robot: float, init_vertices: np.ndarray | None, *, width: int,
                init_radius: float, pretrain_steps: int, learn_com: bool, learn_friction: bool, learn_mass: bool,
                seed: int, geometry: str = "dsf", n_vertices: int = 300) -> ContactModel:
    """``geometry``: "dsf" (deep support function, pre-fitted to the guess) or "polytope" (vertices initialised
    on the guess)."""
    if geometry not in ("dsf", "polytope"):
        raise ValueError(f"geometry must be 'dsf' or 'polytope', got {geometry!r}")
    gen = torch.Generator().manual_seed(seed)
    if init_vertices is not None and len(init_vertices) >= 4:
        V = np.asarray(init_vertices, float)
        L = 0.5 * float(np.linalg.norm(np.ptp(V, axis=0)))
        com, I = solid_hull_inertia(V, mass)
    else:
        V = None
        L = init_radius * math.sqrt(3.0)
        com, I = np.zeros(3), 0.4 * mass * init_radius**2 * np.eye(3)
    poly = PolytopeSupport(polytope_init(V, init_radius, n_vertices)) if geometry == "polytope" else None
    model = ContactModel(width, L, mass, com, I, mu_table, mu_robot, learn_com=learn_com,
                         learn_friction=learn_friction, learn_mass=learn_mass, generator=gen, geometry=poly)
    torch.manual_seed(seed)
    if poly is None:
        init_geometry(model, V, init_radius, pretrain_steps)
    return model


def export(model: ContactModel, grid: int = 8) -> tuple[Mesh, np.ndarray, np.ndarray]:
    d = cube_surface_directions(grid)
    mesh, s = export_mesh(model.geometry, d)
    return mesh, d, s


def current_hull(model: ContactModel, grid: int = 8) -> Mesh:
    return export(model, grid)[0]


def half_extents(mesh: Mesh) -> np.ndarray:
    return 0.5 * np.ptp(np.asarray(mesh.vertices), axis=0)
