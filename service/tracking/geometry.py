"""Rigid registration primitives: back-projection, normals, Kabsch, RANSAC, point-to-plane ICP.

- Back-projection (docs/conventions.md): p_C = d · K⁻¹ [u, v, 1]ᵀ.
- Kabsch / Umeyama without scale: R, t minimising Σ w ‖R a_i + t − b_i‖² from the SVD of the weighted
  cross-covariance, with the reflection fix diag(1, 1, det(V Uᵀ)) (Arun et al. 1987; Umeyama 1991).
- RANSAC (Fischler & Bolles 1981) over 3-point Kabsch hypotheses, batched, then refit on the inliers.
- ICP (Chen & Medioni 1992; Rusinkiewicz & Levoy 2001): source points P (in W) against a model (Q, N) in O.
  Unknown X_OW; each Gauss–Newton step linearises p' = p + ω × p + t (small motion applied in O) and minimises
      Σ ρ((p' − q)·n)  +  λ_pt Σ ‖p' − q‖²  +  λ_f Σ ‖p'_f − b_f‖²
  (point-to-plane with Huber weights, a small point-to-point term against tangential sliding, and 3-D feature
  correspondences), with nearest neighbours inside a shrinking radius (optionally only pairs whose normals agree,
  n_p·n_q > ``normal_cos``); X_OW ← Exp(δ) X_OW.
- Degeneracy (Zhang, Kaess & Singh 2016, "On degeneracy of optimization-based state estimation problems"):
  the point-to-plane normal matrix H = Σ JᵀJ, J = [p × n, n], is made unit-consistent with z = Dδ,
  D = diag(L, L, L, 1, 1, 1) (L = RMS radius of the points: a rotation counts as the arc it moves them),
  H_z = D⁻¹ H D⁻¹, and its eigenvalues are normalised by the point count (λ̂ ≈ 1/3 for a direction every point
  constrains). Directions with λ̂ ≪ 1/3 are (partly) unobservable from the shape: rotation of a body of
  revolution about its axis, sliding along a plane or an extrusion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.transforms import make_X


def backproject(depth: np.ndarray, K: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Points (N,3) in C of pixels (u,v) (N,) with depth (H,W) metres."""
    d = depth[v, u]
    x = (u - K[0, 2]) / K[0, 0] * d
    y = (v - K[1, 2]) / K[1, 1] * d
    return np.stack([x, y, d], 1)


def edge_tol(d, jump: float):
    """The depth step (m) that counts as a discontinuity next to a reading at depth d (m; scalar or array): ``jump``
    plus 2 % of d (the sensor's noise grows with depth)."""
    return jump + 0.02 * d


def depth_continuous(depth: np.ndarray, u: np.ndarray, v: np.ndarray, jump: float, holes: bool = True) -> np.ndarray:
    """(N,) bool: pixels (u,v) (N,) of depth (H,W) metres with a reading whose four neighbours (clamped at the
    border) all have one within ``jump`` + 2 % of its depth. A depth sensor blends the near and far surface at a
    depth discontinuity (flying pixels); these fail the test. ``holes`` False: a neighbour without a reading is
    no evidence of a discontinuity (only neighbours with a reading are compared)."""
    H, W = depth.shape
    d0 = depth[v, u]
    tol = edge_tol(d0, jump)
    ok = d0 > 0
    for du, dv in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        nb = depth[np.clip(v + dv, 0, H - 1), np.clip(u + du, 0, W - 1)]
        same = (nb > 0) & (np.abs(nb - d0) < tol)
        ok &= same if holes else same | (nb <= 0)
    return ok


def pixel_normals(depth: np.ndarray, K: np.ndarray, u: np.ndarray, v: np.ndarray, step: int = 2
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame unit normals (N,3) at pixels (u,v) from central differences of the back-projected depth at
    ±step pixels, oriented toward the camera, and a (N,) bool where all four neighbours have depth."""
    H, W = depth.shape
    s = step
    ok = (u >= s) & (u < W - s) & (v >= s) & (v < H - s)
    uc, vc = np.clip(u, s, W - 1 - s), np.clip(v, s, H - 1 - s)
    pr, pl = backproject(depth, K, uc + s, vc), backproject(depth, K, uc - s, vc)
    pd, pu = backproject(depth, K, uc, vc + s), backproject(depth, K, uc, vc - s)
    ok &= (pr[:, 2] > 0) & (pl[:, 2] > 0) & (pd[:, 2] > 0) & (pu[:, 2] > 0)
    n = np.cross(pr - pl, pd - pu)
    nn = np.linalg.norm(n, axis=1, keepdims=True)
    ok &= nn[:, 0] > 1e-12
    n = n / np.maximum(nn, 1e-12)
    p = backproject(depth, K, uc, vc)
    n[(n * p).sum(1) > 0] *= -1
    return n, ok


def orthonormalize(R: np.ndarray) -> np.ndarray:
    """Nearest rotation (polar factor, det +1) of a 3x3 matrix."""
    U, _, Vt = np.linalg.svd(R)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    return U @ D @ Vt


def kabsch(A: np.ndarray, B: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
    """Pose X (4,4) minimising Σ w_i ‖R a_i + t − b_i‖² for A, B (N,3). Batched: A, B (M,N,3) -> (M,4,4)."""
    A = np.asarray(A, float)
    B = np.asarray(B, float)
    if w is None:
        w = np.ones(A.shape[:-1])
    w = w / np.maximum(w.sum(-1, keepdims=True), 1e-12)
    ca = (w[..., None] * A).sum(-2)
    cb = (w[..., None] * B).sum(-2)
    Hm = np.einsum("...n,...ni,...nj->...ij", w, A - ca[..., None, :], B - cb[..., None, :])
    U, _, Vt = np.linalg.svd(Hm)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
    D = np.zeros(U.shape)
    D[..., 0, 0] = 1
    D[..., 1, 1] = 1
    D[..., 2, 2] = np.where(d == 0, 1, d)
    R = np.swapaxes(Vt, -1, -2) @ D @ np.swapaxes(U, -1, -2)
    t = cb - (R @ ca[..., None])[..., 0]
    return make_X(R, t)


def ransac_rigid(A: np.ndarray, B: np.ndarray, thr: float, iters: int = 200, rng: np.random.Generator | None = None,
                 min_inliers: int = 6, cam: tuple[np.ndarray, np.ndarray, "float | np.ndarray"] | None = None
                 ) -> tuple[np.ndarray | None, np.ndarray]:
    """Robust pose with b ≈ X a from putative correspondences A, B (N,3). Returns (X or None, inlier mask (N,)).

    An inlier lies within ``thr`` (m) of its prediction; with ``cam`` = (K (3,3), X_CA (4,4), px), A being points
    measured by the camera C (X_CA: the frame of A in C), the prediction X⁻¹ b of a is compared in C instead: within
    ``px`` pixels across the ray (reprojection) and ``thr`` along it (depth), the two directions of a keypoint's
    noise (``ray_inliers``; ``px`` a number or one per correspondence (N,))."""
    n = len(A)
    if n < max(3, min_inliers):
        return None, np.zeros(n, bool)
    rng = rng or np.random.default_rng(0)
    idx = np.stack([rng.choice(n, 3, replace=False) for _ in range(iters)])
    Xs = kabsch(A[idx], B[idx])
    if cam is None:
        res = np.linalg.norm(_rotate_all(Xs[:, :3, :3], A) + Xs[:, None, :3, 3] - B[None], axis=-1)
        cnt = (res < thr).sum(1)
        best = int(np.argmax(cnt))
        inl = res[best] < thr
    else:
        inl_all = ray_inliers(A, B, Xs, cam, thr)
        best = int(np.argmax(inl_all.sum(1)))
        inl = inl_all[best]
    if inl.sum() < min_inliers:
        return None, inl
    for _ in range(2):
        X = kabsch(A[inl], B[inl])
        if cam is None:
            new = np.linalg.norm(A @ X[:3, :3].T + X[:3, 3] - B, axis=1) < thr
        else:
            new = ray_inliers(A, B, X[None], cam, thr)[0]
        if new.sum() < min_inliers:
            break
        inl = new
    return kabsch(A[inl], B[inl]), inl


def ray_inliers(A: np.ndarray, B: np.ndarray, Xs: np.ndarray, cam: tuple[np.ndarray, np.ndarray, "float | np.ndarray"],
                thr: float) -> np.ndarray:
    """(M,N) bool: for every hypothesis Xs[m] (M,4,4) with b ≈ X a, whether a (N,3), measured by camera C, lies
    within ``px`` pixels of the prediction X⁻¹ b across the camera ray and within ``thr`` (m) along it (depth);
    ``cam`` = (K (3,3), X_CA (4,4), px), px a number or (N,) one per correspondence. A keypoint's position across
    the ray is its image location (about a pixel), along it the depth reading (a few millimetres at 0.8 m): one
    isotropic ball is either too wide across or too narrow along."""
    K, X_CA, px = cam
    d2, dz = ray_residuals(A, B, Xs, K, X_CA)
    return (d2 < px * px) & (np.abs(dz) < thr)


def ray_residuals(A: np.ndarray, B: np.ndarray, Xs: np.ndarray, K: np.ndarray, X_CA: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Residuals of ``ray_inliers``: for every hypothesis Xs[m] (M,4,4) with b ≈ X a and a (N,3) measured by camera C
    (intrinsics K, X_CA the camera from a's frame), the squared image distance (px², (M,N)) of the prediction X⁻¹ b
    from a, and its depth minus a's along the camera's z (m, (M,N))."""
    Ac = A @ X_CA[:3, :3].T + X_CA[:3, 3]
    Rt = np.swapaxes(Xs[:, :3, :3], 1, 2)  # X⁻¹ = (Rᵀ, −Rᵀ t)
    M = X_CA[None, :3, :3] @ Rt  # rotation of b into C
    m = X_CA[:3, 3][None] - (M @ Xs[:, :3, 3, None])[..., 0]
    Pc = _rotate_all(M, B) + m[:, None]
    z = np.maximum(Pc[..., 2], 1e-6)
    du = K[0, 0] * (Pc[..., 0] / z - Ac[None, :, 0] / Ac[None, :, 2])
    dv = K[1, 1] * (Pc[..., 1] / z - Ac[None, :, 1] / Ac[None, :, 2])
    return du * du + dv * dv, Pc[..., 2] - Ac[None, :, 2]


def _rotate_all(R: np.ndarray, A: np.ndarray) -> np.ndarray:
    """(M,N,3): every rotation R (M,3,3) applied to every point A (N,3), R[m] a[n]. The same sums as
    ``np.einsum("mij,nj->mni", R, A)``, whose reduction over j adds the terms in the order (j=0 + j=2) + j=1 (equal
    bit for bit on the x86-64 numpy this runs on, checked on 300 random sets of 200 hypotheses), at two thirds of its
    cost: three broadcast products instead of einsum's inner loop of three terms per output."""
    out = A[None, :, None, 0] * R[:, None, :, 0]
    out += A[None, :, None, 2] * R[:, None, :, 2]
    out += A[None, :, None, 1] * R[:, None, :, 1]
    return out


@dataclass(frozen=True)
class IcpResult:
    X_WO: np.ndarray  # (4,4)
    inlier_frac: float  # fraction of source points within the inlier distance of the model
    rmse: float  # point-to-plane RMS of those inliers, m
    n_inliers: int
    nn_dist: np.ndarray  # (N,) distance of each source point to its nearest model point (at the solution)


def icp(
    P_W: np.ndarray,
    X_WO: np.ndarray,
    tree,
    Q_O: np.ndarray,
    N_O: np.ndarray,
    *,
    iters: int = 15,
    dist0: float = 0.03,
    dist_min: float = 0.006,
    inlier_dist: float = 0.008,
    w_point: float = 0.05,
    feat_W: np.ndarray | None = None,
    feat_O: np.ndarray | None = None,
    w_feat: float = 0.3,
    N_src: np.ndarray | None = None,
    normal_cos: float = 0.0,
) -> IcpResult:
    """Register points P_W (N,3) to the model (Q_O, N_O) (M,3) with KD-tree ``tree`` over Q_O, from X_WO.

    Optional feature correspondences feat_W (F,3) ↔ feat_O (F,3) enter as point-to-point terms: with weight
    ``w_feat`` (relative to the point set) in all six directions."""
    X_OW = np.linalg.inv(X_WO)
    huber = 0.5 * dist_min
    decay = (dist_min / dist0) ** (1.0 / max(iters - 1, 1))
    nf = 0 if feat_W is None else len(feat_W)
    for it in range(iters):
        thr = max(dist_min, dist0 * decay**it)
        R, t = X_OW[:3, :3], X_OW[:3, 3]
        P = P_W @ R.T + t
        d, j = tree.query(P, distance_upper_bound=thr)
        ok = np.isfinite(d)
        if N_src is not None and normal_cos > 0 and ok.any():
            # normal compatibility: a point of a face the model lacks is not matched to the edge of another face
            ok[ok] &= (N_src[ok] @ R.T * N_O[j[ok]]).sum(1) > normal_cos
        if ok.sum() < 6 and nf < 3:
            break
        p, q, n = P[ok], Q_O[j[ok]], N_O[j[ok]]
        r = ((p - q) * n).sum(1)
        Jp = np.hstack([_cross(p, n), n])
        w = np.where(np.abs(r) < huber, 1.0, huber / np.maximum(np.abs(r), 1e-12))
        Hm = (Jp * w[:, None]).T @ Jp
        g = (Jp * w[:, None]).T @ r
        # point-to-point (against sliding on planes): residual p − q, J = [−[p]×, I]
        if w_point > 0 and len(p):
            Hm += w_point * _pt_H(p)
            g += w_point * _pt_g(p, p - q)
        if nf:
            pf = feat_W @ R.T + t
            e = pf - feat_O
            lam = w_feat * max(len(p), 1) / nf
            rf = np.linalg.norm(e, axis=1)
            wf = np.where(rf < 2 * dist_min, 1.0, 2 * dist_min / np.maximum(rf, 1e-12))
            if w_feat > 0:
                Hm += lam * _pt_H(pf, wf)
                g += lam * _pt_g(pf, e, wf)
        Hm += 1e-9 * np.eye(6) * max(len(p), 1)
        delta = -np.linalg.lstsq(Hm, g, rcond=1e-10)[0]
        if not np.all(np.isfinite(delta)):
            break
        step = np.array([np.linalg.norm(delta[:3]) / 0.3, np.linalg.norm(delta[3:]) / 0.05]).max()
        if step > 1.0:  # trust region: at most 0.3 rad / 5 cm per iteration
            delta = delta / step
        X_OW = _exp_se3(delta) @ X_OW
        if np.linalg.norm(delta[:3]) < 1e-5 and np.linalg.norm(delta[3:]) < 1e-5 and thr <= dist_min:
            break
    return icp_result(X_OW, P_W, tree, Q_O, N_O, inlier_dist)


def icp_result(X_OW: np.ndarray, P_W: np.ndarray, tree, Q_O: np.ndarray, N_O: np.ndarray, inlier_dist: float
               ) -> IcpResult:
    """The registration result of pose X_OW (4,4) (rotation re-orthonormalised) for points P_W (N,3) against model
    points Q_O (M,3) with normals N_O (KD-tree ``tree``): inliers within ``inlier_dist``, their point-to-plane RMSE."""
    X_OW = X_OW.copy()
    X_OW[:3, :3] = orthonormalize(X_OW[:3, :3])
    R, t = X_OW[:3, :3], X_OW[:3, 3]
    P = P_W @ R.T + t
    d, j = tree.query(P, distance_upper_bound=max(inlier_dist, 0.05))
    inl = d < inlier_dist
    r = ((P[inl] - Q_O[j[inl]]) * N_O[j[inl]]).sum(1) if inl.any() else np.zeros(0)
    return IcpResult(
        X_WO=np.linalg.inv(X_OW),
        inlier_frac=float(inl.mean()) if len(P) else 0.0,
        rmse=float(np.sqrt(np.mean(r**2))) if len(r) else np.inf,
        n_inliers=int(inl.sum()),
        nn_dist=np.where(np.isfinite(d), d, np.inf),
    )


def degeneracy(P_O: np.ndarray, N_O: np.ndarray) -> np.ndarray:
    """Normalised eigenvalues λ̂ (6,) (ascending) of the unit-consistent point-to-plane normal matrix of points
    P_O (N,3) with normals N_O (N,3) (module docstring); λ̂ ≪ 1/3 marks a direction the shape does not fix."""
    J = np.hstack([_cross(P_O, N_O), N_O])
    L = float(np.sqrt(np.mean(np.sum((P_O - P_O.mean(0)) ** 2, 1)))) or 1.0
    Di = np.diag([1 / L, 1 / L, 1 / L, 1.0, 1.0, 1.0])
    return np.linalg.eigvalsh(Di @ (J.T @ J) @ Di) / max(len(P_O), 1)


def crease_points(P: np.ndarray, N: np.ndarray, radius: float, cos_min: float, k: int = 12) -> np.ndarray:
    """(N,) bool: points P (N,3) with unit normals N (N,3) that have a neighbour within ``radius`` whose normal
    differs by more than arccos(cos_min) — points at an edge or crease of the surface, whose normals (central
    differences over a few pixels) blend the two faces. In a model they form a chamfer along every edge, and a
    point of a face the model lacks, matched to that chamfer, drags the pose along the directions the model's
    faces leave free (docs/tracking.md, "Strike sessions")."""
    from scipy.spatial import cKDTree

    n = len(P)
    if n < 2 or radius <= 0:
        return np.zeros(n, bool)
    d, j = cKDTree(P).query(P, k=min(k, n), distance_upper_bound=radius)
    ok = np.isfinite(d)
    jj = np.where(ok, j, 0)
    c = np.einsum("nkd,nd->nk", N[jj], N)
    return np.any(ok & (c < cos_min), axis=1)


def _pt_H(p: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
    """Σ w Jᵀ J for residual p' − b with J = [−[p]×, I] (p (N,3))."""
    w = np.ones(len(p)) if w is None else w
    sw = w.sum()
    S = w @ p
    PP = (p * w[:, None]).T @ p
    A = np.trace(PP) * np.eye(3) - PP  # Σ [p]×ᵀ[p]× = Σ |p|² I − p pᵀ
    Sx = np.array([[0, -S[2], S[1]], [S[2], 0, -S[0]], [-S[1], S[0], 0]])
    Hm = np.zeros((6, 6))
    Hm[:3, :3] = A
    Hm[:3, 3:] = Sx  # Σ (−[p]×)ᵀ I = Σ [p]×
    Hm[3:, :3] = Sx.T
    Hm[3:, 3:] = sw * np.eye(3)
    return Hm


def _pt_g(p: np.ndarray, e: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
    """Σ w Jᵀ e for residual e (N,3) with J = [−[p]×, I]: rotation part Σ w p × e."""
    w = np.ones(len(p)) if w is None else w
    return np.concatenate([w @ _cross(p, e), w @ e])


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (N,3) arrays (cheaper than np.cross for small N; written into one array, the
    same products and differences as stacking the three columns)."""
    out = np.empty((len(a), 3), np.result_type(a, b))
    np.subtract(a[:, 1] * b[:, 2], a[:, 2] * b[:, 1], out=out[:, 0])
    np.subtract(a[:, 2] * b[:, 0], a[:, 0] * b[:, 2], out=out[:, 1])
    np.subtract(a[:, 0] * b[:, 1], a[:, 1] * b[:, 0], out=out[:, 2])
    return out


def _exp_se3(delta: np.ndarray) -> np.ndarray:
    """(6,) [ω, t] -> 4x4 with rotation Exp(ω) (Rodrigues) and translation t."""
    w = delta[:3]
    th = float(np.sqrt(w @ w))
    Kx = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    if th < 1e-8:
        R = np.eye(3) + Kx
    else:
        R = np.eye(3) + np.sin(th) / th * Kx + (1 - np.cos(th)) / th**2 * (Kx @ Kx)
    X = np.eye(4)
    X[:3, :3] = R
    X[:3, 3] = delta[3:]
    return X
