"""Tilt closure of egg-like bodies: the rotations about the short axes fixed by texture against early views.

An egg (a near-sphere elongated along one axis) turned about any axis through its centre moves its surface by
little: the point-to-plane normal matrix of the model (``geometry.degeneracy`` scaling, λ̂ ≈ 1/3 for a direction
every point fixes) has all three rotations weak — development egg 512: λ̂ 0.019, 0.028, 0.052 for the rotations
against 0.23–0.57 for the translations — and two nearly equal weak rotations whose eigenvectors mix, which is how
``spin.find_axis`` tells an egg from a bottle (the separation test fails, the radius profile fits). The spin
closure (``service.tracking.spin``) fixes the rotation about the symmetry axis a from texture; the two rotations
about the short axes (the tilt and the heading of a) are left to the registration, which cannot see them: on the
development eggs the long axis is a few degrees off in the frames after a roll, by the same amount across whole
stretches (the keyframes those frames were registered to were attached so).

The same loop closure, on those two directions (Zhang, Kaess & Singh 2016: constraints from another sensor only
along the weak directions of the geometric problem). With e1, e2 ⊥ a and the centre o (the point of the axis at the
mean height of the model points), the corrected pose is X_WO(i) T(ω_i), T(ω) the rotation by ω = β₁e1 + β₂e2 about
o. An interior keypoint p of frame i matched to a keypoint q of an anchor frame j (already corrected), both in O,
says p_O = T(ω_i) q_O + t, t a small offset the texture may carry (estimated, then dropped: the translations are
well fixed by the geometry): linearised, p_O − q_O = −[q_O − o]× (β₁e1 + β₂e2) + t, three rows per match. The
least squares over the matches within ``tol`` of each other, Huber at ``huber`` (IRLS), gives β for frames with at
least ``min_votes`` matches and a well-conditioned 2×2 block; anchors as in the spin chain (frame 0, the latest
corrected frames, a few older ones spread over the session), the matches gated by the previous frame's ω.
Frames without an estimate interpolate ω; ω is median-filtered over ``smooth`` frames; a correction above
``max_deg`` anywhere is not applied (a lost track). Only ω changes; the spin and the translation are kept. Only a model longer along its axis than across it is
corrected (``prolate``): a model smeared by keyframes attached with wrong rotations is not an egg's shape, and the
axis found on it is off.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.transforms import X_inv, make_X, skew, so3_exp


@dataclass
class TiltResult:
    applied: bool  # the model was egg-like and the correction was applied
    omega: np.ndarray  # (N,3) rotation vector (rad) in O about centre_O applied to each frame: X_WO ← X_WO T(ω)
    centre_O: np.ndarray  # (3,) the centre o in O
    votes: np.ndarray  # (N,) matches used by each frame's estimate (0: interpolated)
    rejected: bool = False  # the correction exceeded max_deg somewhere and was not applied


def prolate(Q: np.ndarray, a: np.ndarray, c: np.ndarray) -> bool:
    """True when the model points Q (M,3) reach farther along the axis (a, c) than across it (1st–99th percentile
    extents; across: the larger of two perpendicular directions): an egg's axis is its long one, and the two weak
    rotations the closure measures are about its short axes. A model built from keyframes attached with wrong
    rotations is a smear shorter along the axis found on it than across (development eggs 522, 923: 0.83, 0.73;
    the others 1.08–1.31), and its axis is 10° off: not corrected."""
    from service.tracking.spin import plane_basis

    a = a / np.linalg.norm(a)
    d = Q - c
    ext = [float(np.ptp(np.percentile(d @ e, [1, 99]))) for e in (a, *plane_basis(a))]
    return ext[0] > max(ext[1], ext[2])


def tilt_matrix(omega: np.ndarray, o: np.ndarray) -> np.ndarray:
    """4x4 rotation by the rotation vector omega (3,) about the point o (3,)."""
    R = so3_exp(omega)
    return make_X(R, o - R @ o)


def tilt_step(pO: np.ndarray, qO: np.ndarray, o: np.ndarray, E: np.ndarray, huber: float, iters: int = 5
              ) -> tuple[np.ndarray, int, float]:
    """(β (k,), inliers, conditioning) of p_O ≈ T(E β) q_O + t for matched points p, q (K,3) in O about o; E (3,k)
    the rotation directions, t (3,) a free offset (module docstring); Huber IRLS at ``huber`` (m), inliers within
    2·huber. Conditioning: the smallest over the largest singular value of the β block with t eliminated."""
    K, nb = len(pO), E.shape[1]
    if K < 3:
        return np.zeros(nb), 0, 0.0
    A = np.zeros((K, 3, nb + 3))
    A[:, :, :nb] = -skew(qO - o) @ E
    A[:, :, nb:] = np.eye(3)
    A2 = A.reshape(-1, nb + 3)
    b2 = (pO - qO).reshape(-1)
    w = np.ones(K)
    for _ in range(iters):
        W = np.repeat(w, 3)
        H = A2.T @ (W[:, None] * A2)
        x = np.linalg.solve(H + 1e-12 * np.eye(nb + 3), A2.T @ (W * b2))
        r = np.linalg.norm((A2 @ x - b2).reshape(-1, 3), axis=1)
        w = np.where(r <= huber, 1.0, huber / np.maximum(r, 1e-12))
    W = np.repeat(w, 3)
    H = A2.T @ (W[:, None] * A2)
    S = H[:nb, :nb] - H[:nb, nb:] @ np.linalg.solve(H[nb:, nb:] + 1e-12 * np.eye(3), H[nb:, :nb])
    sv = np.linalg.svd(S, compute_uv=False)
    return x[:nb], int(np.sum(r <= 2 * huber)), float(sv[-1] / sv[0]) if sv[0] > 0 else 0.0


def tilt_closure(feats: list[tuple[np.ndarray, np.ndarray | None]], X_WO: np.ndarray, Q: np.ndarray, a: np.ndarray,
                 c: np.ndarray, *, match, voted: np.ndarray | None = None, tol: float = 0.006, huber: float = 0.002,
                 min_votes: int = 8, min_cond: float = 0.05, n_recent: int = 3, n_spread: int = 8, smooth: int = 5,
                 max_deg: float = 30.0, reach: int = 0) -> TiltResult:
    """Tilt correction ω (N,3) of the poses X_WO (N,4,4) (already spin-corrected) of an egg-like body with symmetry
    axis (a, c) in O (module docstring), from each frame's interior features ``feats[i] = (points (F,3) in W,
    descriptors or None)``; X_WO is not changed (apply with ``apply_tilt``). Q (M,3): the model in O (for the
    centre). ``match(desc_a, desc_b) -> (M,2)``. ``voted`` (N,) bool: only these frames are estimated (the frames
    whose spin the texture measured: where the spin is interpolated, its error enters the matches and, through an
    axis a few degrees off, the fitted tilt); the others interpolate. ``reach`` > 0: a frame d frames from the nearest
    estimated frame keeps max(0, 1 − d/reach) of its interpolated correction (``reach_weights``): beyond that the
    loop's own pose is kept, not a correction measured elsewhere (0: interpolated and held at the ends everywhere)."""
    from service.tracking.spin import anchor_candidates, plane_basis

    n = len(X_WO)
    a = a / np.linalg.norm(a)
    o = c + float(np.mean((Q - c) @ a)) * a
    E = np.stack(plane_basis(a), 1)  # (3,2)
    beta = np.zeros((n, 2))
    votes = np.zeros(n, int)
    Xc = X_WO.copy()  # corrected poses of the anchors
    Xc_inv: dict[int, np.ndarray] = {}
    anchors = [0]
    for i in range(1, n):
        kp, des = feats[i]
        if des is None or len(kp) < min_votes or (voted is not None and not voted[i]):
            continue
        _, cand = anchor_candidates(anchors, n_recent, n_spread)
        prev = anchors[-1]
        Xpi = X_inv(X_WO[i] @ tilt_matrix(E @ beta[prev], o))  # frame i with the previous frame's correction
        pO_all = kp @ Xpi[:3, :3].T + Xpi[:3, 3]
        P, Qm = [], []
        for j in cand:
            kq, dq = feats[j]
            m = match(des, dq)
            if len(m) == 0:
                continue
            if j not in Xc_inv:
                Xc_inv[j] = X_inv(Xc[j])
            Xj = Xc_inv[j]
            qO = kq[m[:, 1]] @ Xj[:3, :3].T + Xj[:3, 3]
            pO = pO_all[m[:, 0]]
            ok = np.linalg.norm(pO - qO, axis=1) < tol
            P.append(pO[ok])
            Qm.append(qO[ok])
        pO = np.concatenate(P) if P else np.zeros((0, 3))
        if len(pO) < min_votes:
            continue
        db, inl, cond = tilt_step(pO, np.concatenate(Qm), o, E, huber)
        if inl < min_votes or cond < min_cond:
            continue
        # p_O (with the previous correction) = T(E db) q_O: X_WO(i) T(E β_prev) T(E db); small angles add
        beta[i] = beta[prev] + db
        votes[i] = inl
        Xc[i] = X_WO[i] @ tilt_matrix(E @ beta[i], o)
        anchors.append(i)
    ok = votes > 0
    ok[0] = True
    idx = np.nonzero(ok)[0]
    full = np.stack([np.interp(np.arange(n), idx, beta[idx, k]) for k in range(2)], 1)
    if smooth > 1:
        from scipy.ndimage import median_filter

        full = median_filter(full, size=(smooth, 1), mode="nearest")
    full[0] = 0.0
    omega = full @ E.T
    if max_deg > 0 and np.max(np.linalg.norm(omega, axis=1)) > np.radians(max_deg):
        return TiltResult(False, np.zeros((n, 3)), o, votes, rejected=True)
    if reach > 0:
        omega = omega * reach_weights(votes > 0, reach)[:, None]
    return TiltResult(True, omega, o, votes)


def reach_weights(voted: np.ndarray, reach: int) -> np.ndarray:
    """(N,) weights max(0, 1 − d/reach), d the distance (frames) of each frame from the nearest True of ``voted``
    (N,) bool; frame 0 (the gauge, correction 0) does not count as one. All zeros when nothing is voted."""
    n = len(voted)
    idx = np.nonzero(voted)[0]
    idx = idx[idx > 0]
    if len(idx) == 0:
        return np.zeros(n)
    k = np.arange(n)
    pos = np.searchsorted(idx, k)
    left, right = idx[np.clip(pos - 1, 0, len(idx) - 1)], idx[np.clip(pos, 0, len(idx) - 1)]
    d = np.minimum(np.abs(k - left), np.abs(k - right))
    return np.clip(1.0 - d / float(reach), 0.0, 1.0)


def apply_tilt(X_WO: np.ndarray, res: TiltResult) -> np.ndarray:
    """X_WO (N,4,4) with each frame turned by its ω about the centre: X_WO(i) T(ω_i)."""
    if not res.applied:
        return X_WO.copy()
    return np.stack([X @ tilt_matrix(w, res.centre_O) for X, w in zip(X_WO, res.omega)])
