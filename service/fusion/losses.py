"""Contact-induced SDF losses of Vysics §4.B (paper Eqs. loss_support_point, loss_hyperplane, loss_convex).

S is the SDF being fitted (metres), queried through ``query_fn(x (M,3) float32 tensor) -> (M,)``.
Following BundleSDF, whose network predicts S in truncation units, every residual is divided by
τ (= 1 cm), so the paper's weights (support point 2, hyperplane 1, convexity 1) sit on the same scale
as the depth terms (near-surface 3000, empty space 1, uncertain free space 50).

- support point:  L_sp  = mean_j ((S(x_j) − l_j) / τ)²                     on ray samples (x, l)
- hyperplane:     L_hc  = mean_k (min(0, S(q_k) − b_k) / τ)²                S(q) ≥ b = (q − v)·m̂
- convexity:      L_cvx = mean_{valid} max(0, S(x) − (t S̄(s₁) + (1 − t) l₂)) / τ,
                  x = t s₁ + (1 − t) s₂, s₁ a near-surface point (|S(s₁)| ≤ ε), s₂ a ray sample with
                  target l₂; S̄(s₁) is S(s₁) detached (the bound is a target, not trained through).
                  Convexity of the SDF of a convex body makes S(x) ≤ t S(s₁) + (1 − t) S(s₂).

``PhysibleLosses`` is the ``extra_losses`` callable given to ``service.sdf.fit_sdf``: each step it
draws up to n_sp / n_hc / n_cvx samples from fixed pools (seeded) and returns the weighted sum.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from service.fusion.types import LossWeights

QueryFn = Callable[[torch.Tensor], torch.Tensor]


def sp_from_values(S: torch.Tensor, target: torch.Tensor, tau: float) -> torch.Tensor:
    """mean ((S − l)/τ)² of SDF values (M,) and targets (M,) (0 when M = 0)."""
    if len(S) == 0:
        return torch.zeros(())
    return (((S - target) / tau) ** 2).mean()


def hc_from_values(S: torch.Tensor, bound: torch.Tensor, tau: float) -> torch.Tensor:
    """mean (min(0, S − b)/τ)² of SDF values (M,) and lower bounds (M,) (0 when M = 0)."""
    if len(S) == 0:
        return torch.zeros(())
    return (torch.clamp((S - bound) / tau, max=0.0) ** 2).mean()


def support_point_loss(query_fn: QueryFn, x: torch.Tensor, target: torch.Tensor, tau: float) -> torch.Tensor:
    """x (M,3), target (M,) metres -> scalar mean ((S(x) − l)/τ)²."""
    if len(x) == 0:
        return torch.zeros(())
    return sp_from_values(query_fn(x), target, tau)


def hyperplane_loss(query_fn: QueryFn, q: torch.Tensor, bound: torch.Tensor, tau: float) -> torch.Tensor:
    """q (M,3), lower bound (M,) metres -> scalar mean (min(0, S(q) − b)/τ)²."""
    if len(q) == 0:
        return torch.zeros(())
    return hc_from_values(query_fn(q), bound, tau)


def convexity_pairs(
    S1: torch.Tensor, s1: torch.Tensor, s2: torch.Tensor, l2: torch.Tensor, t: torch.Tensor, eps: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Interpolated points x (K,3) and upper bounds (K,) of the pairs whose S(s₁) (M,) is within ε.

    x = t s₁ + (1 − t) s₂, bound = t S(s₁) + (1 − t) l₂ (S(s₁) detached)."""
    valid = S1.detach().abs() <= eps
    s1, s2, l2, t, S1 = s1[valid], s2[valid], l2[valid], t[valid], S1.detach()[valid]
    x = t[:, None] * s1 + (1.0 - t[:, None]) * s2
    return x, t * S1 + (1.0 - t) * l2


def convexity_hinge(S_x: torch.Tensor, bound: torch.Tensor, tau: float) -> torch.Tensor:
    """mean max(0, S(x) − bound)/τ over (K,) pairs (0 when K = 0)."""
    if len(S_x) == 0:
        return torch.zeros(())
    return torch.relu((S_x - bound) / tau).mean()


def convexity_loss(
    query_fn: QueryFn,
    s1: torch.Tensor,
    s2: torch.Tensor,
    l2: torch.Tensor,
    t: torch.Tensor,
    tau: float,
    eps: float,
) -> torch.Tensor:
    """s1, s2 (M,3), l2 (M,), t (M,) in [0,1] -> scalar mean over pairs with |S(s₁)| ≤ ε of
    max(0, S(t s₁ + (1 − t) s₂) − (t S̄(s₁) + (1 − t) l₂)) / τ (0 when no pair is valid)."""
    if len(s1) == 0:
        return torch.zeros(())
    with torch.no_grad():
        S1 = query_fn(s1)
    x, bound = convexity_pairs(S1, s1, s2, l2, t, eps)
    if len(x) == 0:
        return torch.zeros(())
    return convexity_hinge(query_fn(x), bound, tau)


class PhysibleLosses:
    """``extra_losses`` callable for ``fit_sdf``: weighted L_sp + L_hc + L_cvx on per-step subsets.

    Pools (numpy, frame O): ray samples ``x_sp`` (M,3) with targets ``l_sp`` (M,); hyperplane samples
    ``q_hc`` (K,3) with bounds ``b_hc`` (K,); near-surface points ``s_vis`` (V,3) for convexity.
    """

    def __init__(
        self,
        x_sp: np.ndarray,
        l_sp: np.ndarray,
        q_hc: np.ndarray,
        b_hc: np.ndarray,
        s_vis: np.ndarray,
        weights: LossWeights,
        tau: float,
        seed: int = 0,
    ):
        f = lambda a: torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))  # noqa: E731
        self.x_sp, self.l_sp = f(np.reshape(x_sp, (-1, 3))), f(np.reshape(l_sp, -1))
        self.q_hc, self.b_hc = f(np.reshape(q_hc, (-1, 3))), f(np.reshape(b_hc, -1))
        self.s_vis = f(np.reshape(s_vis, (-1, 3)))
        if len(self.x_sp) != len(self.l_sp) or len(self.q_hc) != len(self.b_hc):
            raise ValueError("sample pools and their targets must have the same length")
        self.w = weights
        self.tau = float(tau)
        self.gen = torch.Generator().manual_seed(int(seed))
        self.last: dict[str, float] = {}

    def _pick(self, n_pool: int, n: int) -> torch.Tensor:
        if n_pool <= n:
            return torch.arange(n_pool)
        return torch.randint(0, n_pool, (n,), generator=self.gen)

    def __call__(self, query_fn: QueryFn, step: int) -> torch.Tensor:
        """Weighted sum of the three terms on this step's subsets; one differentiable grid query for
        all of them (each query's backward scatters into the whole grid, so one is cheaper than three)."""
        w = self.w
        pts, n = [], {}
        use_sp = w.sp > 0 and len(self.x_sp) > 0
        use_hc = w.hc > 0 and len(self.q_hc) > 0
        use_cvx = w.cvx > 0 and len(self.x_sp) > 0 and len(self.s_vis) > 0
        if use_sp:
            i = self._pick(len(self.x_sp), w.n_sp)
            pts.append(self.x_sp[i])
            l_sp = self.l_sp[i]
            n["sp"] = len(i)
        if use_hc:
            i = self._pick(len(self.q_hc), w.n_hc)
            pts.append(self.q_hc[i])
            b_hc = self.b_hc[i]
            n["hc"] = len(i)
        if use_cvx:
            i1 = torch.randint(0, len(self.s_vis), (w.n_cvx,), generator=self.gen)
            i2 = torch.randint(0, len(self.x_sp), (w.n_cvx,), generator=self.gen)
            t = torch.rand(w.n_cvx, generator=self.gen)
            s1 = self.s_vis[i1]
            with torch.no_grad():
                S1 = query_fn(s1)
            x_cvx, bound = convexity_pairs(S1, s1, self.x_sp[i2], self.l_sp[i2], t, w.eps_cvx)
            pts.append(x_cvx)
            n["cvx"] = len(x_cvx)
        if not pts:
            self.last = {}
            return torch.zeros(())
        S = query_fn(torch.cat(pts))
        parts, a = {}, 0
        for key in ("sp", "hc", "cvx"):
            if key not in n:
                continue
            Sk = S[a:a + n[key]]
            a += n[key]
            if key == "sp":
                parts[key] = sp_from_values(Sk, l_sp, self.tau)
            elif key == "hc":
                parts[key] = hc_from_values(Sk, b_hc, self.tau)
            else:
                parts[key] = convexity_hinge(Sk, bound, self.tau)
        total = sum(getattr(w, k) * v for k, v in parts.items())
        self.last = {k: float(v.detach()) for k, v in parts.items()}
        return total
