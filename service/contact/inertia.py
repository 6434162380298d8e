"""Physically consistent rigid-body inertia by log-Cholesky parameters (Rucker & Wensing 2022; PLL ``inertia.py``).

θ = [c (3), d (3), s (3)]:  L = [[e^{d₁},0,0],[s₁₂,e^{d₂},0],[s₁₃,s₂₃,e^{d₃}]],  Σ = L Lᵀ (second moment of
the mass distribution about the CoM per unit mass), central inertia I_c = m (tr(Σ) I₃ − Σ).
Every θ gives a valid inertia (Σ ≻ 0 ⇒ I_c ≻ 0 and the triangle inequalities hold).
Inverse: Σ = ½ tr(I_c/m) I₃ − I_c/m, then Cholesky. Mass m = exp(log m) is fixed by default (impulses
scale with m, so it is not observable from motion alone).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn


def sigma_from_inertia(I_c: np.ndarray, mass: float) -> np.ndarray:
    J = np.asarray(I_c, float) / mass
    return 0.5 * np.trace(J) * np.eye(3) - J


def params_from_inertia(I_c: np.ndarray, mass: float) -> tuple[np.ndarray, np.ndarray]:
    """(d (3), s (3)) for a central inertia (3,3) with I_c ≻ 0 that satisfies the triangle inequalities."""
    L = np.linalg.cholesky(sigma_from_inertia(I_c, mass))
    return np.log(np.diag(L)), np.array([L[1, 0], L[2, 0], L[2, 1]])


def inertia_from_params(d: torch.Tensor, s: torch.Tensor, mass: torch.Tensor) -> torch.Tensor:
    """Central inertia (3,3) from log-Cholesky parameters."""
    z = torch.zeros((), dtype=d.dtype)
    e = torch.exp(d)
    L = torch.stack(
        [torch.stack([e[0], z, z]), torch.stack([s[0], e[1], z]), torch.stack([s[1], s[2], e[2]])]
    )
    S = L @ L.T
    return mass * (torch.trace(S) * torch.eye(3, dtype=d.dtype) - S)


def solid_box_inertia(half_extents, mass: float) -> np.ndarray:
    a, b, c = 2 * np.asarray(half_extents, float)
    return mass / 12.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])


def solid_hull_inertia(vertices: np.ndarray, mass: float) -> tuple[np.ndarray, np.ndarray]:
    """(CoM (3,), central inertia (3,3)) of the uniform solid convex hull of vertices (V,3)."""
    from service.contact.geometry import hull_mesh

    m = hull_mesh(vertices).to_trimesh()
    vol = abs(float(m.volume))
    if vol < 1e-12:
        ext = np.ptp(np.asarray(vertices, float), axis=0) / 2 + 1e-3
        return np.asarray(vertices, float).mean(0), solid_box_inertia(ext, mass)
    com = np.asarray(m.center_mass, float)
    I = np.asarray(m.moment_inertia, float) / vol * mass  # trimesh: density 1, about the CoM
    return com, 0.5 * (I + I.T)


class RigidBodyInertia(nn.Module):
    """Mass (fixed unless ``learn_mass``), CoM c_O (3,) and log-Cholesky moments."""

    def __init__(self, mass: float, com: np.ndarray, inertia: np.ndarray, *, learn_com: bool = True,
                 learn_mass: bool = False):
        super().__init__()
        d, s = params_from_inertia(inertia, mass)
        lm = torch.tensor(np.log(mass), dtype=torch.float64)
        self.log_mass = nn.Parameter(lm) if learn_mass else nn.Parameter(lm, requires_grad=False)
        self.com = nn.Parameter(torch.as_tensor(np.asarray(com, float)), requires_grad=learn_com)
        self.d = nn.Parameter(torch.as_tensor(d, dtype=torch.float64))
        self.s = nn.Parameter(torch.as_tensor(s, dtype=torch.float64))

    @property
    def mass(self) -> torch.Tensor:
        return torch.exp(self.log_mass)

    def central_inertia(self) -> torch.Tensor:
        return inertia_from_params(self.d, self.s, self.mass)
