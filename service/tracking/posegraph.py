"""Keyframe bundle adjustment: joint refinement of all keyframe poses from their pairwise overlaps.

Unknowns: X_OW^k of keyframes k = 1..K−1 (keyframe 0 is fixed: it defines O). Each keyframe k has points
p^k (N_k,3) with normals n^k observed in W; in O they are P^k = X_OW^k p^k. For every ordered pair (a, b) of
keyframes whose point sets overlap, nearest neighbours q ∈ P^a of the points p ∈ P^b within a shrinking
radius (normals compatible) give point-to-plane residuals
    r = n_q · (p − q).
With small motions applied in O, X_OW^k ← Exp(δ_k) X_OW^k, δ_k = [ω_k, τ_k]:
    ∂r/∂δ_b = [p × n, n],  ∂r/∂δ_a = −[p × n, n].
The robust cost Σ ρ_H(r) (Huber) is minimised by
iteratively reweighted Gauss–Newton with Levenberg damping on the stacked δ (6(K−1) unknowns, dense normal
equations), correspondences re-found at every outer iteration (multi-view ICP; Pulli 1999, "Multiview
registration for large data sets"; the global pose-graph refinement of BundleSDF, Wen et al. 2023, with
point-to-plane terms in place of its learned ones). Keyframe 0 is not perturbed, which removes the
gauge freedom; a weak prior w_prior·N_k·‖[ℓ·Log(R_k R_k,0ᵀ), t_k − R_k R_k,0ᵀ t_k,0]‖² toward the tracked poses
(ℓ = 0.1 m) holds directions that no overlap constrains (a keyframe that sees a single plane).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from service.tracking.geometry import _cross, _exp_se3, orthonormalize
from service.transforms import skew


@dataclass
class BAResult:
    X_OW: np.ndarray  # (K,4,4) refined poses (X_OW[0] unchanged)
    n_pairs: int  # overlapping pairs used in the last iteration
    cost0: float  # robust cost at the start (per residual)
    cost: float  # robust cost at the end (per residual)


def bundle_adjust(
    X_OW: np.ndarray,
    P_W: list[np.ndarray],
    N_W: list[np.ndarray],
    *,
    iters: int = 10,
    dist0: float = 0.012,
    dist_min: float = 0.004,
    huber: float = 0.002,
    min_overlap: float = 0.1,
    min_pairs_pts: int = 30,
    normal_cos: float = 0.7,
    w_point: float = 0.05,
    max_points: int = 600,
    w_prior: float = 0.01,
    rng: np.random.Generator | None = None,
) -> BAResult:
    """Jointly refine keyframe poses X_OW (K,4,4) from their points P_W[k] (N_k,3) and normals N_W[k] in W.

    Pairs overlap when at least ``min_overlap`` of the smaller set has a
    neighbour within the current radius."""
    rng = rng or np.random.default_rng(0)
    K = len(X_OW)
    X = np.array(X_OW, float).copy()
    X_start = X.copy()
    if K < 2:
        return BAResult(X, 0, 0.0, 0.0)
    # subsample each keyframe's points
    P, Nn = [], []
    for p, n in zip(P_W, N_W):
        if len(p) > max_points:
            s = rng.choice(len(p), max_points, replace=False)
            p, n = p[s], n[s]
        P.append(np.asarray(p, float))
        Nn.append(np.asarray(n, float))
    decay = (dist_min / dist0) ** (1.0 / max(iters - 1, 1))
    cost0 = cost = 0.0
    n_pairs = 0
    lam = 1e-3
    for it in range(iters):
        thr = max(dist_min, dist0 * decay**it)
        PO = [p @ x[:3, :3].T + x[:3, 3] for p, x in zip(P, X)]
        NO = [n @ x[:3, :3].T for n, x in zip(Nn, X)]
        trees = [cKDTree(p) if len(p) else None for p in PO]
        # axis-aligned boxes in O: a pair whose boxes are farther apart than thr has no correspondence (exact skip)
        lo = np.array([p.min(0) if len(p) else np.full(3, np.inf) for p in PO])
        hi = np.array([p.max(0) if len(p) else np.full(3, -np.inf) for p in PO])
        D = 6 * K
        H = np.zeros((D, D))
        g = np.zeros(D)
        tot, nres = 0.0, 0
        n_pairs = 0
        for a in range(K):
            if trees[a] is None:
                continue
            for b in range(K):
                if b == a or not len(PO[b]):
                    continue
                if np.any(lo[b] > hi[a] + thr) or np.any(lo[a] > hi[b] + thr):
                    continue
                d, j = trees[a].query(PO[b], distance_upper_bound=thr)
                ok = np.isfinite(d)
                if ok.any():
                    ok[ok] &= (NO[b][ok] * NO[a][j[ok]]).sum(1) > normal_cos
                m = int(ok.sum())
                if m < min_pairs_pts or m < min_overlap * min(len(PO[a]), len(PO[b])):
                    continue
                n_pairs += 1
                p, q, nq = PO[b][ok], PO[a][j[ok]], NO[a][j[ok]]
                r = ((p - q) * nq).sum(1)
                w = np.where(np.abs(r) < huber, 1.0, huber / np.maximum(np.abs(r), 1e-12))
                tot += float(np.sum(np.where(np.abs(r) < huber, 0.5 * r**2, huber * (np.abs(r) - 0.5 * huber))))
                nres += m
                J = np.hstack([_cross(p, nq), nq])  # ∂r/∂δ_b; ∂r/∂δ_a = −J
                Hb = (J * w[:, None]).T @ J
                gb = (J * w[:, None]).T @ r
                if w_point > 0:  # small point-to-point term against sliding along planes
                    e = p - q
                    Jp = np.concatenate([-skew(p), np.broadcast_to(np.eye(3), (m, 3, 3))], 2)  # (m,3,6)
                    Hb = Hb + w_point * np.einsum("nki,nkj->ij", Jp, Jp)
                    gb = gb + w_point * np.einsum("nki,nk->i", Jp, e)
                _add_pair(H, g, a, b, Hb, gb)
        # weak prior toward the starting poses: keeps directions that no overlap constrains (a keyframe seeing
        # one plane only) where tracking put them; residual [ℓ·Log(R R0ᵀ), t − R R0ᵀ t0], ℓ = 0.1 m
        for k in range(1, K):
            D_k = X[k] @ np.linalg.inv(X_start[k])
            e = np.concatenate([0.1 * _so3_log(D_k[:3, :3]), D_k[:3, 3]])
            wk = w_prior * len(P[k])
            Jd = np.array([0.1, 0.1, 0.1, 1.0, 1.0, 1.0])
            ik = slice(6 * k, 6 * k + 6)
            H[ik, ik] += wk * np.diag(Jd * Jd)
            g[ik] += wk * Jd * e
        c = tot / max(nres, 1)
        if it == 0:
            cost0 = c
        cost = c
        if n_pairs == 0:
            break
        Hr, gr = H[6:, 6:], g[6:]  # keyframe 0 fixed
        dg = np.diag(Hr).copy()
        free = dg > 1e-12  # keyframes with no constraint keep their pose
        delta = np.zeros(D - 6)
        if free.any():
            Hf = Hr[np.ix_(free, free)]
            Hf = Hf + lam * np.diag(dg[free]) + 1e-9 * np.eye(int(free.sum()))
            delta[free] = -np.linalg.solve(Hf, gr[free])
        for k in range(1, K):
            dk = delta[6 * (k - 1): 6 * k]
            if not np.all(np.isfinite(dk)):
                continue
            s = max(np.linalg.norm(dk[:3]) / 0.05, np.linalg.norm(dk[3:]) / 0.01, 1.0)  # trust region
            X[k] = _exp_se3(dk / s) @ X[k]
            X[k][:3, :3] = orthonormalize(X[k][:3, :3])
    return BAResult(X, n_pairs, cost0, cost)


def _so3_log(R: np.ndarray) -> np.ndarray:
    from service.transforms import so3_log

    return np.asarray(so3_log(R), float)


def _add_pair(H: np.ndarray, g: np.ndarray, a: int, b: int, Hb: np.ndarray, gb: np.ndarray) -> None:
    """Add a pair term whose Jacobian is J for keyframe b and −J for keyframe a."""
    ia, ib = slice(6 * a, 6 * a + 6), slice(6 * b, 6 * b + 6)
    H[ib, ib] += Hb
    H[ia, ia] += Hb
    H[ia, ib] -= Hb
    H[ib, ia] -= Hb
    g[ib] += gb
    g[ia] -= gb
