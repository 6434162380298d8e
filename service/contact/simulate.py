"""Open-loop simulation of a convex rigid body on the table (z = 0): Anitescu convex time stepping (method-notes §2.5).

At (q, ν): v⁻ = ν + dt M⁻¹F(q, ν); contacts = the ``n_contacts`` lowest vertices of the convex geometry with
gaps φ_i (heights) and Jacobian rows J = [e_z; μ e_x; μ e_y]ᵀ J_p (μ folded in, as in learning);
λ = argmin_{λ∈Π Lorentz cones} ½ λᵀ J M⁻¹ Jᵀ λ + λᵀ (J v⁻ + [φ/dt; 0; 0]);  ν⁺ = v⁻ + M⁻¹Jᵀλ;
then semi-implicit Euler (q⁺ = q ⊕ dt ν⁺). The same cone solver as learning is used (tighter tolerance,
warm-started from the previous step). Batched over trajectories. Table only (no robot): used for tosses.

Errors: per-step position error ‖p_sim − p_true‖ and geodesic rotation error, averaged over the rollout.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from service.contact import dynamics as dyn
from service.contact.solver import SolverSettings, solve_cone_qp


@dataclass(frozen=True)
class Body:
    vertices_O: np.ndarray  # (V,3) convex geometry (hull vertices), m
    mass: float
    com_O: np.ndarray  # (3,)
    inertia_O: np.ndarray  # (3,3) about the CoM
    mu_table: float


def merge_vertices(V: np.ndarray, tol: float = 0.003) -> np.ndarray:
    """Greedy merge of vertices closer than ``tol`` (a learned hull has clusters of support points at its
    corners; without merging the ``n_contacts`` lowest vertices can all sit in one corner)."""
    V = np.asarray(V, float)
    keep: list[np.ndarray] = []
    for v in V[np.argsort(V[:, 2])]:
        if not keep or np.min(np.linalg.norm(np.asarray(keep) - v, axis=-1)) > tol:
            keep.append(v)
    return np.asarray(keep)


def box_vertices(half_extents) -> np.ndarray:
    h = np.asarray(half_extents, float)
    s = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    return s * h


@torch.no_grad()
def simulate(body: Body, x0: np.ndarray, n_steps: int, dt: float, *, n_contacts: int = 8, substeps: int = 1,
             solver: SolverSettings = SolverSettings(max_iters=300, eps_rel=1e-6, eps_abs=1e-10)) -> np.ndarray:
    """Roll out B initial states x0 (B,13) (table at z = 0) for n_steps of dt. Returns (B, n_steps+1, 13)."""
    x0 = np.atleast_2d(np.asarray(x0, float))
    B = len(x0)
    V = torch.as_tensor(np.asarray(body.vertices_O, float))
    k = min(n_contacts, len(V))
    m = torch.tensor(float(body.mass), dtype=torch.float64)
    c = torch.as_tensor(np.asarray(body.com_O, float))
    Ic = torch.as_tensor(np.asarray(body.inertia_O, float))
    mu = float(body.mu_table)
    quat = torch.as_tensor(x0[:, 0:4].copy())
    quat = quat / quat.norm(dim=-1, keepdim=True)
    p = torch.as_tensor(x0[:, 4:7].copy())
    nu = torch.as_tensor(x0[:, 7:13].copy())
    h = dt / substeps
    ez = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    ex = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    ey = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    out = np.zeros((B, n_steps + 1, 13))
    out[:, 0] = np.concatenate([quat.numpy(), p.numpy(), nu.numpy()], -1)
    lam = None
    for t in range(n_steps):
        for _ in range(substeps):
            R = dyn.quat_to_mat(quat)
            M = dyn.mass_matrix(R, m, c, Ic)
            F = dyn.bias_force(R, nu, m, c, Ic)
            v_minus = nu + h * torch.linalg.solve(M, F.unsqueeze(-1)).squeeze(-1)
            zW = (V @ R.transpose(-1, -2))[..., 2] + p[:, 2:3]  # (B,V)
            phi, idx = torch.topk(zW, k, dim=-1, largest=False)
            r = V[idx]  # (B,k,3)
            Rb = R.unsqueeze(1)
            rows = [dyn.direction_rows(Rb, r, u.expand_as(r)) for u in (ez, ex, ey)]
            J = torch.stack([rows[0], mu * rows[1], mu * rows[2]], 2).reshape(B, 3 * k, 6)
            Minv_Jt = torch.linalg.solve(M, J.transpose(-1, -2))
            P = J @ Minv_Jt
            P = 0.5 * (P + P.transpose(-1, -2))
            q = (J @ v_minus.unsqueeze(-1)).squeeze(-1)
            q = q + torch.stack([phi / h, torch.zeros_like(phi), torch.zeros_like(phi)], -1).reshape(B, 3 * k)
            lam = solve_cone_qp(P, q, solver, x0=lam).x
            nu = v_minus + (Minv_Jt @ lam.unsqueeze(-1)).squeeze(-1)
            quat, p = dyn.integrate(quat, p, nu, h)
        out[:, t + 1] = np.concatenate([quat.numpy(), p.numpy(), nu.numpy()], -1)
    return out


def rollout_errors(sim: np.ndarray, true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-step position error (m) and geodesic rotation error (rad) between state arrays (…,T,13)."""
    from service.transforms import quat_to_mat, rotation_angle

    pos = np.linalg.norm(sim[..., 4:7] - true[..., 4:7], axis=-1)
    Rs = quat_to_mat(sim[..., 0:4])
    Rt = quat_to_mat(true[..., 0:4])
    rot = rotation_angle(np.swapaxes(Rt, -1, -2) @ Rs)
    return pos, rot


def rollout_trajectories(body: Body, trajs, dt: float, *, n_contacts: int = 8, table_height: float = 0.0,
                         substeps: int = 1, merge_tol: float = 0.003) -> dict:
    """Simulate each trajectory from its first state for its length; mean position/rotation errors.
    Vertices closer than ``merge_tol`` are merged first (see ``merge_vertices``)."""
    trajs = [np.asarray(X, float) for X in trajs]
    if merge_tol > 0:
        body = Body(merge_vertices(body.vertices_O, merge_tol), body.mass, body.com_O, body.inertia_O, body.mu_table)
    T = max(len(X) for X in trajs)
    x0 = np.stack([X[0] for X in trajs])
    x0[:, 6] -= table_height
    sim = simulate(body, x0, T - 1, dt, n_contacts=n_contacts, substeps=substeps)
    sim[..., 6] += table_height
    pos_all, rot_all, per = [], [], []
    for i, X in enumerate(trajs):
        pe, re = rollout_errors(sim[i, : len(X)], X)
        pos_all.append(pe)
        rot_all.append(re)
        per.append((float(pe.mean()), float(np.degrees(re.mean()))))
    pos = np.concatenate(pos_all)
    rot = np.concatenate(rot_all)
    return {
        "pos_err_m": float(np.mean([a for a, _ in per])),
        "rot_err_deg": float(np.mean([b for _, b in per])),
        "pos_err_median_m": float(np.median([a for a, _ in per])),
        "rot_err_median_deg": float(np.median([b for _, b in per])),
        "final_pos_err_m": float(np.mean([np.linalg.norm(sim[i, len(X) - 1, 4:7] - X[-1, 4:7]) for i, X in enumerate(trajs)])),
        "per_trajectory": per,
        "steps": int(pos.size),
        "sim": sim,
    }
