"""Free-body rigid dynamics in the PLL coordinates (torch, batched), method-notes §2.6.

Generalised velocity ν = [ω (body axes); v_o (world)], pose (R = R_WO, p = p_WO), mass m, CoM c (in O),
central inertia I_c (O axes), I_o = I_c + m [c]×ᵀ[c]×, gravity g = (0, 0, −9.81):

    M(q) = [[I_o, m [c]× Rᵀ], [−m R [c]×, m I₃]]
    F(q, ν) = [−ω × I_o ω + m c × (Rᵀ g);  −m R (ω × (ω × c)) + m g]

(Newton–Euler about the body origin; verified against the CoM form in the tests.) A world force f at
a body point r (O coordinates) enters as the generalised force Jᵀf with the point Jacobian
J = [−R [r]×, I₃], so a row uᵀJ for a world direction u is [r × (Rᵀu), u].

Semi-implicit Euler (PLL ``VelocityIntegrator``): ν_{k+1} from (q, ν), then p_{k+1} = p_k + dt v_{k+1},
quat_{k+1} = quat_k ⊗ Exp(dt ω_{k+1}).
"""

from __future__ import annotations

import torch

GRAVITY = 9.81


def skew(v: torch.Tensor) -> torch.Tensor:
    z = torch.zeros_like(v[..., 0])
    return torch.stack(
        [
            torch.stack([z, -v[..., 2], v[..., 1]], -1),
            torch.stack([v[..., 2], z, -v[..., 0]], -1),
            torch.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )


def quat_to_mat(q: torch.Tensor) -> torch.Tensor:
    q = q / q.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def quat_mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        -1,
    )


def quat_exp(r: torch.Tensor) -> torch.Tensor:
    """Rotation vector (…,3) -> wxyz quaternion."""
    th = r.norm(dim=-1, keepdim=True)
    half = 0.5 * th
    k = torch.where(th < 1e-10, 0.5 - th**2 / 48.0, torch.sin(half) / th.clamp_min(1e-300))
    return torch.cat([torch.cos(half), r * k], -1)


def mass_matrix(R: torch.Tensor, mass: torch.Tensor, com: torch.Tensor, I_c: torch.Tensor) -> torch.Tensor:
    """M (B,6,6) for rotations R (B,3,3)."""
    B = R.shape[0]
    C = skew(com)
    I_o = I_c + mass * C.T @ C
    top = torch.cat([I_o.expand(B, 3, 3), mass * C @ R.transpose(-1, -2)], -1)
    bot = torch.cat([-mass * R @ C, mass * torch.eye(3, dtype=R.dtype).expand(B, 3, 3)], -1)
    return torch.cat([top, bot], -2)


def bias_force(R: torch.Tensor, nu: torch.Tensor, mass: torch.Tensor, com: torch.Tensor, I_c: torch.Tensor) -> torch.Tensor:
    """F(q, ν) (B,6): gyroscopic + gravity generalised force (see module docstring)."""
    w = nu[:, :3]
    C = skew(com)
    I_o = I_c + mass * C.T @ C
    g = torch.tensor([0.0, 0.0, -GRAVITY], dtype=R.dtype)
    gB = (R.transpose(-1, -2) @ g)  # (B,3)
    Iw = w @ I_o.T
    Fw = -torch.cross(w, Iw, dim=-1) + mass * torch.cross(com.expand_as(gB), gB, dim=-1)
    wxc = torch.cross(w, com.expand_as(w), dim=-1)
    wwc = torch.cross(w, wxc, dim=-1)
    Fv = -mass * (R @ wwc.unsqueeze(-1)).squeeze(-1) + mass * g
    return torch.cat([Fw, Fv], -1)


def direction_rows(R: torch.Tensor, r_O: torch.Tensor, u_W: torch.Tensor) -> torch.Tensor:
    """Jacobian rows uᵀJ(r) (…,6) for body points r_O (…,3) and world directions u_W (…,3).
    R broadcasts as (B,1,3,3) against (B,k,3)."""
    uB = (R.transpose(-1, -2) @ u_W.unsqueeze(-1)).squeeze(-1)
    return torch.cat([torch.cross(r_O, uB, dim=-1), u_W], -1)


def integrate(quat: torch.Tensor, p: torch.Tensor, nu_next: torch.Tensor, dt: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Semi-implicit Euler pose update with the new velocity ν_{k+1} (B,6)."""
    q_next = quat_mul(quat, quat_exp(dt * nu_next[:, :3]))
    q_next = q_next / q_next.norm(dim=-1, keepdim=True)
    return q_next, p + dt * nu_next[:, 3:]
