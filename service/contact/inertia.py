"""Physically consistent rigid-body inertia by log-Cholesky parameters (Rucker & Wensing 2022; PLL ``inertia.py``).

θ = [c (3), d (3), s (3)]:  L = [[e^{d₁},0,0],[s₁₂,e^{d₂},0],[s₁₃,s₂₃,e^{d₃}]],  Σ = L Lᵀ (second moment of
the mass distribution about the CoM per unit mass), central inertia I_c = m (tr(Σ) I₃ − Σ).
Every θ gives a valid inertia (Σ ≻ 0 ⇒ I_c ≻ 0 and the triangle inequalities hold).
Inverse: Σ = ½ tr(I_c/m) I₃ − I_c/m, then Cholesky. Mass m = exp(log m) is fixed by default (impulses
scale with m, so it is not observable from motion alone).

Density realizability (Wensing, Kim & Slotine 2017, "Linear matrix inequalities for physically consistent
inertial parameter identification"): a mass distribution inside the ellipsoid E = {x : (x − e)ᵀA(x − e) ≤ 1}
has ∫ρ (x − e)ᵀA(x − e) dx ≤ m, i.e. tr(A (Σ + (c − e)(c − e)ᵀ)) ≤ 1 (which also keeps the CoM c inside E).
Log-Cholesky parameters guarantee Σ ≻ 0 only; they allow a body whose inertia no mass inside its own shape
could have. ``realizability_ratio`` > 1 measures how far θ is outside the bound of the ellipsoid enclosing
the current geometry (``enclosing_ellipsoid``, Khachiyan's minimum-volume algorithm).

CoM prior (``com_centroid_penalty``): (c − ĉ)ᵀA(c − ĉ), with ĉ the uniform-density centroid of the current hull and A
the shape matrix of its enclosing ellipsoid (scale-free: 1 when the offset reaches the ellipsoid's surface). Where
the motion leaves the CoM weakly observed (objects sliding flat), it ties c to the shape as a uniform body would.
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


def enclosing_ellipsoid(points: np.ndarray, tol: float = 1e-3, max_iter: int = 500) -> tuple[np.ndarray, np.ndarray]:
    """Minimum-volume ellipsoid {x : (x − e)ᵀA(x − e) ≤ 1} enclosing points (P,3) (Khachiyan 1996, as in
    Todd & Yıldırım 2007). Returns (e (3,), A (3,3)). Degenerate (flat) point sets get a 1 mm thickness."""
    P = np.asarray(points, float)
    P = P + 1e-3 * np.random.default_rng(0).standard_normal(P.shape) * (np.ptp(P, axis=0).min() < 1e-3)
    n, d = P.shape
    Q = np.vstack([P.T, np.ones(n)])  # (4,n)
    u = np.full(n, 1.0 / n)
    for _ in range(max_iter):
        X = (Q * u) @ Q.T
        M = np.einsum("in,ij,jn->n", Q, np.linalg.inv(X), Q)
        j = int(np.argmax(M))
        step = (M[j] - d - 1.0) / ((d + 1.0) * (M[j] - 1.0))
        new_u = (1.0 - step) * u
        new_u[j] += step
        done = np.linalg.norm(new_u - u) < tol
        u = new_u
        if done:
            break
    e = P.T @ u
    A = np.linalg.inv((P.T * u) @ P - np.outer(e, e)) / d
    # Khachiyan's ellipsoid encloses the points only up to tol: scale it to contain every point exactly
    r = np.einsum("ni,ij,nj->n", P - e, A, P - e).max()
    return e, A / max(r, 1.0)


def realizability_ratio(inertia: "RigidBodyInertia", e: torch.Tensor, A: torch.Tensor) -> torch.Tensor:
    """tr(A (Σ + (c − e)(c − e)ᵀ)): ≤ 1 when the inertia and CoM can come from a mass distribution inside the
    ellipsoid (e, A) (module docstring); differentiable in the log-Cholesky parameters and the CoM."""
    z = torch.zeros((), dtype=inertia.d.dtype)
    ex = torch.exp(inertia.d)
    s = inertia.s
    L = torch.stack([torch.stack([ex[0], z, z]), torch.stack([s[0], ex[1], z]), torch.stack([s[1], s[2], ex[2]])])
    dc = inertia.com - e
    return torch.trace(A @ (L @ L.T)) + dc @ A @ dc


def com_centroid_penalty(com: torch.Tensor, centroid: torch.Tensor, A: torch.Tensor) -> torch.Tensor:
    """(c − ĉ)ᵀA(c − ĉ) for the CoM c (3,), a centroid ĉ (3,) and an ellipsoid shape matrix A (3,3) (module
    docstring); differentiable in c."""
    dc = com - centroid
    return dc @ A @ dc
