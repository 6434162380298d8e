"""Silhouette term of the pose registration: the object mask constrains the directions point-to-plane ICP
leaves free (sliding along the edge shared by the only faces seen moves the silhouette, not the depth).

Every point q_O of the object must project, with the pose X_WO, inside the object mask of the view or onto a
pixel whose depth reading lies in front of it (an occluder, the robot). For the model points
(ICP model plus the keyframes' *rim* points, below), projected at (u, v) with camera depth z,
    r_i = max(0, D(u, v) − ½ − t)   (pixels),
where D is the Euclidean distance transform of the mask's complement (distance of a pixel centre to the
nearest mask pixel centre, bilinear; the object's edge lies ½ px outside the outermost mask pixel centres)
and t = ``tol_px``. A point is skipped when the nearest reading d outside the mask within ``occ_px`` of its
pixel (the object's own readings and dropouts left out) is d < z − ``occ_margin`` (occluded: the mask boundary
there is an occlusion edge, not the object's outline), when there is no such reading (dropouts line every
depth discontinuity), or when it projects outside the image. Residuals in metres (r z / f_x), Huber at
``huber_px``, points beyond ``max_px`` dropped (model noise, gross misfit), weight ``w_sil`` per point
relative to one point-to-plane term. With X_OW ← Exp(δ) X_OW (δ = [ω, τ] in O), ∂p_W/∂δ = R_WO [[q]×, −I], and
    ∂r/∂δ = ∇D · ∂π/∂p_C · R_CW · ∂p_W/∂δ   (π the pinhole projection).
The term is one-sided: a model that covers only part of the object (unseen sides) is never pulled outwards.

Free space (``w_front``): the outline hardly moves when the free direction points along the line of sight (a
5 mm slide there changes a 40 px outline by 0.4 px), but the model's faces then stick out in front of the surface
the camera sees. A model point projecting inside the mask onto an object reading d (continuous depth, bilinear
between four valid pixels) must not lie in front of it: r = d − z − ``front_margin`` > 0 (metres, along the ray,
the reading held fixed: ∂r/∂δ = −∂z/∂δ), Huber ``front_huber``, as in the free-space constraints of
model-based depth trackers (Schmidt, Newcombe & Fox 2014, DART). One-sided, it pushes away from the camera when
the margin is small against the depth noise (``front_back``: a two-sided band instead, weaker; docs/tracking.md).

Noise (``smooth_points``, ``smooth_front``, ``weak_projector``, ``front_violations``): the model is the union of
keyframe depth points (3 mm voxel centroids of few readings), scattered about the surface like one reading (lab
σ = 0.8 + 1.8 z² mm); against the frame's own noisy reading 20–30 % of the points of a model built with the *true*
poses lie more than 2 mm in front of it, so the one-sided term's minimum lies ~1 mm farther from the camera than the
truth. Options: model points moved onto the plane of their neighbours and the reading averaged over 3×3 pixels;
the terms restricted to the weak directions of the point-to-plane Hessian; a per-frame gate on the fraction of
points in front of the reading (docs/tracking.md).

Rim points: the tracking points come from the mask eroded by ``erode_px`` (mixed depth at silhouettes), so
an edge seen only as a silhouette would sit 2–3 px inside the model's true outline and leave that much slack.
The ring between the mask and its erosion is kept for the silhouette model when its depth agrees with the
eroded interior next to it (normalised convolution; mixed pixels between object and background fail; 2 mm +
0.5 % of the depth: with the tracking points' 1 cm + 2 % about 1 % of the rim points of a strike session
lay 5–17 mm off the true surface, with it none beyond 4.3 mm), above the table clearance and away from the end effector.

Registration (``refine``): a few Gauss–Newton iterations of the point-to-plane ICP cost (robust, the final
correspondence radius of ``geometry.icp``, small point-to-point term) plus the two terms, from the pose
ICP found (Lepetit & Fua 2005, silhouette-based tracking; the chamfer/distance-transform form as in
Prisacariu & Reid 2012, PWP3D, reduced to its one-sided outside part).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.tracking.geometry import IcpResult, _cross, _exp_se3, _pt_g, _pt_H, icp_result


@dataclass
class SilhouetteView:
    """One view's mask distance transform and depth for the silhouette term."""

    K: np.ndarray  # (3,3)
    X_CW: np.ndarray  # (4,4)
    dist: np.ndarray  # (H,W) float32: distance (px) of each pixel centre to the nearest mask pixel centre
    gu: np.ndarray  # (H,W) its derivative along u
    gv: np.ndarray  # (H,W) along v
    occ: np.ndarray  # (H,W) float32 nearest reading outside the mask within occ_px (inf: none)
    front: np.ndarray  # (H,W) float32 object depth for the free-space part (0: none: outside the mask, dropout,
    # depth jump to a 4-neighbour, i.e. a flying pixel)
    u0: int = 0  # the arrays cover pixels [v0, v0 + H) x [u0, u0 + W) of the image (a crop around the mask)
    v0: int = 0


def make_view(depth: np.ndarray, mask: np.ndarray, K: np.ndarray, X_WC: np.ndarray, occ_px: int = 2,
              jump: float = 0.01, pad: int | None = 16, front_smooth_px: int = 0) -> SilhouetteView:
    """Distance transform of the complement of ``mask`` (H,W) bool, its gradient, and the nearest depth reading
    outside the mask within ``occ_px`` pixels (min filter; readings of the object itself and dropouts, which
    line every depth discontinuity, left out). With ``pad`` the arrays cover only the mask's bounding box grown by
    pad pixels (points farther outside lie beyond ``max_px`` of the term and count as outside the image). With
    ``front_smooth_px`` k > 0 the free-space reading is the mean of the continuous object readings in the
    (2k+1)² window (at least half of it valid; ``smooth_front``)."""
    import cv2

    u0 = v0 = 0
    if pad is not None and mask.any():
        rows, cols = np.nonzero(mask.any(1))[0], np.nonzero(mask.any(0))[0]
        v0, v1 = max(rows[0] - pad, 0), min(rows[-1] + pad + 1, mask.shape[0])
        u0, u1 = max(cols[0] - pad, 0), min(cols[-1] + pad + 1, mask.shape[1])
        mask, depth = mask[v0:v1, u0:u1], depth[v0:v1, u0:u1]

    m = np.ascontiguousarray(np.where(mask, 0, 255).astype(np.uint8))
    D = cv2.distanceTransform(m, cv2.DIST_L2, cv2.DIST_MASK_PRECISE).astype(np.float32)
    gu = np.zeros_like(D)
    gv = np.zeros_like(D)
    gu[:, 1:-1] = 0.5 * (D[:, 2:] - D[:, :-2])
    gv[1:-1, :] = 0.5 * (D[2:, :] - D[:-2, :])
    occ = np.where(~mask & (depth > 0), depth, np.inf).astype(np.float32)
    if occ_px > 0:
        occ = cv2.erode(occ, np.ones((2 * occ_px + 1, 2 * occ_px + 1), np.uint8))  # erosion = min filter
    d = np.asarray(depth, np.float32)
    ok = mask & (d > 0)
    tol = jump + 0.02 * d
    for ax, sh in ((0, 1), (0, -1), (1, 1), (1, -1)):
        nb = np.roll(d, sh, axis=ax)
        ok &= (nb > 0) & (np.abs(nb - d) < tol)
    front = np.where(ok, d, 0.0).astype(np.float32)
    if front_smooth_px > 0:
        front = smooth_front(front, front_smooth_px)
    return SilhouetteView(np.asarray(K, float), np.linalg.inv(X_WC), D, gu, gv, occ, front, int(u0), int(v0))


def rim_points(depth: np.ndarray, mask: np.ndarray, K: np.ndarray, X_WC: np.ndarray, erode_px: int,
               table_height: float, table_clearance: float, jump: float = 0.002, rel: float = 0.005) -> np.ndarray:
    """(R,3) points in W of the mask pixels removed by the erosion (the rim) whose depth agrees within
    ``jump`` + ``rel`` × the depth with the mean depth of the eroded interior within erode_px + 2 px, above the
    table clearance. Empty when erode_px is 0 (the tracking points reach the outline already)."""
    import cv2

    if erode_px <= 0 or not mask.any():
        return np.zeros((0, 3))
    k = 2 * erode_px + 1
    m = mask.astype(np.uint8)
    me = cv2.erode(m, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))) > 0
    valid = depth > 0
    inner = (me & valid).astype(np.float32)
    r = erode_px + 2
    box = (2 * r + 1, 2 * r + 1)
    s = cv2.boxFilter(np.where(inner > 0, depth, 0).astype(np.float32), -1, box, normalize=False)
    c = cv2.boxFilter(inner, -1, box, normalize=False)
    ring = mask & ~me & valid & (c > 0.5)
    v, u = np.nonzero(ring)
    if len(u) == 0:
        return np.zeros((0, 3))
    d = depth[v, u].astype(float)
    d_in = s[v, u] / c[v, u]
    ok = np.abs(d - d_in) < jump + rel * d
    u, v, d = u[ok], v[ok], d[ok]
    P_C = np.stack([(u - K[0, 2]) / K[0, 0] * d, (v - K[1, 2]) / K[1, 1] * d, d], 1)
    P_W = P_C @ X_WC[:3, :3].T + X_WC[:3, 3]
    return P_W[P_W[:, 2] > table_height + table_clearance]


def _bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    H, W = img.shape
    u0 = np.clip(np.floor(u).astype(int), 0, W - 2)
    v0 = np.clip(np.floor(v).astype(int), 0, H - 2)
    a = np.clip(u - u0, 0.0, 1.0)
    b = np.clip(v - v0, 0.0, 1.0)
    return ((1 - a) * (1 - b) * img[v0, u0] + a * (1 - b) * img[v0, u0 + 1]
            + (1 - a) * b * img[v0 + 1, u0] + a * b * img[v0 + 1, u0 + 1])


def silhouette_terms(Q_O: np.ndarray, X_OW: np.ndarray, view: SilhouetteView, *, tol_px: float = 0.0,
                     occ_margin: float = 0.005, huber_px: float = 1.0, max_px: float = 8.0, w_sil: float = 1.0,
                     w_front: float = 0.0, front_margin: float = 0.002, front_huber: float = 0.002,
                     front_max: float = 0.02, front_back: float | None = None
                     ) -> tuple[np.ndarray, np.ndarray, float, int]:
    """Gauss–Newton pieces of the silhouette term for points Q_O (M,3) at pose X_OW: (H (6,6), g (6,), cost,
    number of active points), in metres, weighted by ``w_sil``, for the update X_OW ← Exp(δ) X_OW. With
    ``w_front`` > 0 also the free-space part: a point projecting inside the mask onto an object reading d
    (continuous depth, bilinear between four valid pixels) must not lie in front of it, r = d − z − front_margin > 0 (up to front_max; Huber
    at front_huber), ∂r/∂δ = −∂z/∂δ (the reading held fixed). With ``front_back`` (m) instead the two-sided band
    −front_back < r = d − z < front_max (points on the seen surface pull both ways, so the reading's noise does
    not push the object away from the camera; points hidden deeper than front_back are left out)."""
    X_WO = np.linalg.inv(X_OW)
    X_CO = view.X_CW @ X_WO
    P = Q_O @ X_CO[:3, :3].T + X_CO[:3, 3]
    z = P[:, 2]
    K = view.K
    H_img, W_img = view.dist.shape
    zz = np.where(z > 1e-6, z, 1.0)
    u = K[0, 0] * P[:, 0] / zz + K[0, 2] - view.u0  # crop coordinates
    v = K[1, 1] * P[:, 1] / zz + K[1, 2] - view.v0
    ins = (z > 1e-6) & (u >= 0) & (u <= W_img - 1) & (v >= 0) & (v <= H_img - 1)
    Hm, g = np.zeros((6, 6)), np.zeros(6)
    if not ins.any():
        return Hm, g, 0.0, 0
    cost_f, n_f = 0.0, 0
    if w_front > 0:
        jf = np.nonzero(ins)[0]
        Fh, Fw = view.front.shape
        u0 = np.clip(np.floor(u[jf]).astype(int), 0, Fw - 2)
        v0 = np.clip(np.floor(v[jf]).astype(int), 0, Fh - 2)
        f00, f01, f10, f11 = (view.front[v0, u0], view.front[v0, u0 + 1], view.front[v0 + 1, u0],
                              view.front[v0 + 1, u0 + 1])
        ok4 = (f00 > 0) & (f01 > 0) & (f10 > 0) & (f11 > 0)
        aa = np.clip(u[jf] - u0, 0.0, 1.0)
        bb = np.clip(v[jf] - v0, 0.0, 1.0)
        d_f = np.where(ok4, (1 - aa) * (1 - bb) * f00 + aa * (1 - bb) * f01 + (1 - aa) * bb * f10 + aa * bb * f11,
                       0.0)  # a slanted face: interpolate
        if front_back is None:  # one-sided: only points in front of the reading by more than the margin
            rf = d_f - z[jf] - front_margin
            a = ok4 & (rf > 0) & (rf < front_max)
        else:  # two-sided band: the noise of the reading pushes both ways
            rf = d_f - z[jf]
            a = ok4 & (rf > -front_back) & (rf < front_max)
        jf, rf = jf[a], rf[a]
        if len(jf):
            # ∂r/∂p_C = −e_z: the reading is held fixed (its image gradient across a crease or the edge of a
            # grazing face would trade the push along the ray for a sub-pixel slide), i.e. the point moves along z
            b = np.broadcast_to(-X_CO[2, :3], (len(jf), 3))  # R_COᵀ(−e_z), in O
            Jf = np.hstack([-_cross(Q_O[jf], b), -b])
            ar = np.abs(rf)
            wf = np.where(ar < front_huber, 1.0, front_huber / np.maximum(ar, 1e-12))
            Hm += w_front * (Jf * wf[:, None]).T @ Jf
            g += w_front * (Jf * wf[:, None]).T @ rf
            cost_f = w_front * float(np.sum(np.where(ar < front_huber, 0.5 * rf**2,
                                                     front_huber * (ar - 0.5 * front_huber))))
            n_f = len(jf)
    idx = np.nonzero(ins)[0]
    D = _bilinear(view.dist, u[idx], v[idx])
    r_px = D - 0.5 - tol_px
    act = (r_px > 0) & (r_px < max_px)
    idx, r_px = idx[act], r_px[act]
    if len(idx) == 0:
        return Hm, g, cost_f, n_f
    ui = np.clip(np.round(u[idx]).astype(int), 0, W_img - 1)
    vi = np.clip(np.round(v[idx]).astype(int), 0, H_img - 1)
    d_obs = view.occ[vi, ui]
    vis = np.isfinite(d_obs) & (d_obs >= z[idx] - occ_margin)  # a reading seen there, not in front of the point
    idx, r_px = idx[vis], r_px[vis]
    if len(idx) == 0:
        return Hm, g, cost_f, n_f
    p, zi = P[idx], z[idx]
    du = _bilinear(view.gu, u[idx], v[idx])
    dv = _bilinear(view.gv, u[idx], v[idx])
    # ∂(u,v)/∂p_C, then ∂r/∂p_C = du ∂u/∂p_C + dv ∂v/∂p_C
    drdp = np.stack([du * K[0, 0] / zi, dv * K[1, 1] / zi,
                     -(du * K[0, 0] * p[:, 0] + dv * K[1, 1] * p[:, 1]) / zi**2], 1)
    # p_C = R_CO q + t with R_CO = R_CW R_WO; ∂p_C/∂δ = R_CO [[q]×, −I]
    drdq = drdp @ X_CO[:3, :3]  # (n,3) = (R_COᵀ ∂r/∂p_C)ᵀ
    q = Q_O[idx]
    J = np.hstack([-_cross(q, drdq), -drdq])  # a·([q]× ω) = (q × ω)·a ... = −(q × a)·ω
    scale = zi / K[0, 0]  # px -> m
    r = r_px * scale
    J = J * scale[:, None]
    hub = huber_px * scale
    w = np.where(r < hub, 1.0, hub / np.maximum(r, 1e-12))
    Hm += w_sil * (J * w[:, None]).T @ J
    g += w_sil * (J * w[:, None]).T @ r
    cost = w_sil * float(np.sum(np.where(r < hub, 0.5 * r**2, hub * (r - 0.5 * hub))))
    return Hm, g, cost + cost_f, len(idx) + n_f


def refine(P_W: np.ndarray, X_WO: np.ndarray, tree, Q_O: np.ndarray, N_O: np.ndarray, sil_Q: np.ndarray,
           view: SilhouetteView, *, iters: int = 5, dist: float = 0.006, inlier_dist: float = 0.008,
           w_point: float = 0.05, w_sil: float = 1.0, tol_px: float = 0.0, occ_margin: float = 0.005,
           huber_px: float = 1.0, max_px: float = 8.0, w_front: float = 0.0, front_margin: float = 0.002,
           front_back: float | None = None, weak_ratio: float = 0.0, weak_len: float = 0.05) -> IcpResult:
    """Point-to-plane registration of P_W (N,3) to the model (Q_O, N_O, ``tree``) plus the silhouette term of
    the model points ``sil_Q`` (M,3) in ``view``, from X_WO; returns the pose with the inlier fraction and
    residual computed like ``geometry.icp``. With ``weak_ratio`` > 0 the silhouette and free-space terms act only
    along the weak directions of the point-to-plane Hessian at the start (``weak_projector``); X_WO unchanged when
    there is none."""
    X_OW = np.linalg.inv(X_WO)
    huber = 0.5 * dist
    M = None
    for it in range(iters):
        R, t = X_OW[:3, :3], X_OW[:3, 3]
        P = P_W @ R.T + t
        d, j = tree.query(P, distance_upper_bound=dist)
        ok = np.isfinite(d)
        Hm, g = np.zeros((6, 6)), np.zeros(6)
        n = int(ok.sum())
        if n >= 6:
            p, q, nn = P[ok], Q_O[j[ok]], N_O[j[ok]]
            r = ((p - q) * nn).sum(1)
            Jp = np.hstack([_cross(p, nn), nn])
            w = np.where(np.abs(r) < huber, 1.0, huber / np.maximum(np.abs(r), 1e-12))
            Hm += (Jp * w[:, None]).T @ Jp
            g += (Jp * w[:, None]).T @ r
            if weak_ratio > 0 and M is None:  # the weak directions of the point-to-plane part, at the start
                M = weak_projector(Hm, weak_len, weak_ratio)
                if M is None:
                    break  # depth constrains every direction: nothing for the terms to do
            if w_point > 0:
                Hm += w_point * _pt_H(p)
                g += w_point * _pt_g(p, p - q)
        Hs, gs, _, ns = silhouette_terms(sil_Q, X_OW, view, tol_px=tol_px, occ_margin=occ_margin,
                                         huber_px=huber_px, max_px=max_px, w_sil=w_sil, w_front=w_front,
                                         front_margin=front_margin, front_back=front_back)
        if n < 6 and ns == 0:
            break
        if weak_ratio > 0:
            if M is None:
                break  # too few depth pairs to tell the weak directions
            Hs, gs = M.T @ Hs @ M, M.T @ gs
        Hm += Hs
        g += gs
        Hm += 1e-9 * np.eye(6) * max(n, 1)
        delta = -np.linalg.lstsq(Hm, g, rcond=1e-10)[0]
        if not np.all(np.isfinite(delta)):
            break
        step = max(np.linalg.norm(delta[:3]) / 0.05, np.linalg.norm(delta[3:]) / 0.005)
        if step > 1.0:  # small steps: this refines a converged ICP pose
            delta = delta / step
        X_OW = _exp_se3(delta) @ X_OW
        if np.linalg.norm(delta[:3]) < 1e-5 and np.linalg.norm(delta[3:]) < 1e-5:
            break
    return icp_result(X_OW, P_W, tree, Q_O, N_O, inlier_dist)


def model_points(parts: list[np.ndarray], voxel: float, max_points: int) -> np.ndarray:
    """Union of point sets (in O) on a voxel grid (one centroid per voxel), at most ``max_points`` (even
    stride, no random draw)."""
    P = np.concatenate([p for p in parts if len(p)]) if any(len(p) for p in parts) else np.zeros((0, 3))
    if len(P) == 0:
        return P
    key = np.floor(P / voxel).astype(np.int64)
    from service.tracking.voxels import group_sums, voxel_groups

    inv, cnt = voxel_groups(key)  # np.unique(key, axis=0)'s groups and np.add.at's sums, faster
    Q = group_sums(inv, P, len(cnt))
    Q /= cnt[:, None]
    if len(Q) > max_points:
        Q = Q[np.linspace(0, len(Q) - 1, max_points).round().astype(int)]
    return Q


def weak_projector(H: np.ndarray, length: float, ratio: float) -> np.ndarray | None:
    """(6,6) map M such that a term with Jacobian J (in δ = [ω, τ]) restricted to the weak directions of the
    point-to-plane Hessian H (6,6) has Jacobian J M: with S = diag(L, L, L, 1, 1, 1) (rotation as the motion of a
    point at ``length`` L), the eigenvectors V_w of S⁻¹ H S⁻¹ whose eigenvalues are below ``ratio`` × the largest
    span the weak subspace and M = S⁻¹ V_w V_wᵀ S. None when no direction is weak (or H is zero)."""
    s = np.array([length] * 3 + [1.0] * 3)
    Hs = H / np.outer(s, s)
    lam, V = np.linalg.eigh(0.5 * (Hs + Hs.T))
    if not lam[-1] > 0:
        return None
    Vw = V[:, lam < ratio * lam[-1]]
    if Vw.shape[1] == 0:
        return None
    return (Vw @ Vw.T) * (s[None, :] / s[:, None])  # S⁻¹ V_w V_wᵀ S


def front_violations(Q_O: np.ndarray, X_OW: np.ndarray, view: SilhouetteView, margin: float
                     ) -> tuple[int, int]:
    """(number of points of Q_O (M,3) at pose X_OW that project inside the mask onto a continuous object reading
    d (four valid neighbours) and lie in front of it by more than ``margin`` (m), number projecting onto such a
    reading): evidence that the model sticks out into space the frame sees empty."""
    X_CO = view.X_CW @ np.linalg.inv(X_OW)
    P = Q_O @ X_CO[:3, :3].T + X_CO[:3, 3]
    z = P[:, 2]
    K = view.K
    Fh, Fw = view.front.shape
    zz = np.where(z > 1e-6, z, 1.0)
    u = K[0, 0] * P[:, 0] / zz + K[0, 2] - view.u0
    v = K[1, 1] * P[:, 1] / zz + K[1, 2] - view.v0
    ins = (z > 1e-6) & (u >= 0) & (u <= Fw - 1) & (v >= 0) & (v <= Fh - 1)
    u, v, z = u[ins], v[ins], z[ins]
    u0 = np.clip(np.floor(u).astype(int), 0, Fw - 2)
    v0 = np.clip(np.floor(v).astype(int), 0, Fh - 2)
    f = [view.front[v0, u0], view.front[v0, u0 + 1], view.front[v0 + 1, u0], view.front[v0 + 1, u0 + 1]]
    ok = (f[0] > 0) & (f[1] > 0) & (f[2] > 0) & (f[3] > 0)
    a, b = np.clip(u - u0, 0.0, 1.0), np.clip(v - v0, 0.0, 1.0)
    d = (1 - a) * (1 - b) * f[0] + a * (1 - b) * f[1] + (1 - a) * b * f[2] + a * b * f[3]
    return int(np.sum(ok & (d - z > margin))), int(np.sum(ok))


def smooth_front(front: np.ndarray, k: int) -> np.ndarray:
    """(H,W) float32: the mean of the positive readings of ``front`` (0: none) in the (2k+1)² window around each
    positive pixel, 0 where fewer than half of the window is positive. The per-pixel depth noise (σ = 0.8 + 1.8 z²
    mm of the lab, 1.6–2 mm at the sessions' 0.6–0.8 m, mostly independent per pixel) would otherwise put 10–20 %
    of the points of a correctly placed model more than 2 mm in front of their reading, and the one-sided term pushes
    the object away from the camera to clear them; averaging over (2k+1)² pixels divides the independent part by
    2k+1 (a plane is unchanged)."""
    import cv2

    valid = (front > 0).astype(np.float32)
    box = (2 * k + 1, 2 * k + 1)
    s = cv2.boxFilter(front.astype(np.float32), -1, box, normalize=False, borderType=cv2.BORDER_CONSTANT)
    c = cv2.boxFilter(valid, -1, box, normalize=False, borderType=cv2.BORDER_CONSTANT)
    ok = (front > 0) & (c >= 0.5 * (2 * k + 1) ** 2)
    return np.where(ok, s / np.maximum(c, 1.0), 0.0).astype(np.float32)


def smooth_points(Q: np.ndarray, radius: float, min_nb: int = 6) -> np.ndarray:
    """(M,3) points Q moved onto the least-squares plane of their neighbours within ``radius`` (one moving
    least-squares step: q ← q − ((q − μ)·n) n, μ the neighbours' mean, n the normal of their covariance); points with
    fewer than ``min_nb`` neighbours unchanged. The model is the union of keyframe depth points (3 mm voxel centroids
    of few readings each), so its points scatter about the surface as much as one reading; measured against a
    reading, 20–30 % of them lie more than 2 mm in front of it at the true pose, and the one-sided free-space term
    pushes the object away from the camera to clear them."""
    from scipy.spatial import cKDTree

    if len(Q) < min_nb:
        return Q
    pairs = cKDTree(Q).query_pairs(radius, output_type="ndarray")
    M = len(Q)
    a = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(M)])  # each point is its own neighbour too
    b = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(M)])
    cnt = np.bincount(a, minlength=M).astype(float)
    mu = np.stack([np.bincount(a, Q[b, k], M) for k in range(3)], 1) / cnt[:, None]
    D = Q[b] - mu[a]
    C = np.zeros((M, 3, 3))
    for k in range(3):
        for l in range(k, 3):
            C[:, k, l] = C[:, l, k] = np.bincount(a, D[:, k] * D[:, l], M)
    n = np.linalg.eigh(C)[1][:, :, 0]
    out = Q - (((Q - mu) * n).sum(1))[:, None] * n
    ok = cnt >= min_nb
    return np.where(ok[:, None], out, Q)
