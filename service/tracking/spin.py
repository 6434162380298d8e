"""Spin closure for bodies of revolution: the rotation about the symmetry axis fixed by texture against early views.

A body of revolution turned about its own axis leaves its surface, hence every point-to-plane residual, unchanged:
ICP cannot see that spin, only the texture can. The tracking loop matches ORB features against the previous frame
and the latest keyframes, so a spin error made once (keypoints at the silhouette or an occluder edge follow the
outline, not the surface) is carried on. This pass ties the spin of every frame to frame 0, which defines O.

Axis. The weak direction of the point-to-plane normal matrix of the final model, H = Σ JᵀJ, J = [p × n, n]
(``geometry.degeneracy``; Zhang, Kaess & Singh 2016): for a surface of revolution every normal line meets the
axis, so the screw ξ = (ω, v) with ω = a (unit axis) and v = c × a (c on the axis) gives n·(ω × p + v) = 0 for
every point. The shape counts as a body of revolution when the smallest normalised eigenvalue λ̂_1 (unit-consistent
scaling, ≈ 1/3 for a direction every point fixes) is below ``spin_tau``, at most ``spin_sep`` times the next one
and its eigenvector is mostly rotation; then a = ω/|ω|, c = ω × v / |ω|². Boxes, prisms and planes (weak
directions, if any, are slides) are left alone; a long prism that the λ̂ test still accepts is refused by where its
normals point (``flat_faced``). An egg's noisy model has two nearly equal weak rotations (λ̂ 0.020
and 0.028 on the development egg 512) whose eigenvectors mix (23° off its axis), or a slide weakest and the axis
next: then (``find_axis``, profile "mixed") the axis is refitted to the radius profile of the model points
(``profile_axis``: r − ρ(h) minimal for a polynomial profile ρ, positions only; 512: 23° → 5°).

Spin per frame (a one-parameter loop closure). With S(θ) the rotation by θ about (a, c) in O, the corrected pose
is X_WO(i) S(θ_i). ORB keypoints are taken only ``spin_border_px`` inside the object mask (away from the
silhouette and occluder edges, so that they move with the surface). A keypoint p of frame i matched to a keypoint q
of an anchor frame j (already corrected) gives, in O, p_O = X_WO(i)⁻¹ p_W and q_O = X_WO(j)⁻¹ q_W; when their
radius about the axis and height along it agree (within ``spin_tol``), θ = φ(p_O) − φ(q_O) (azimuths about a).
θ_i is the mode of these votes (the largest set within ±``spin_inlier_deg``, then its median), accepted with at
least ``spin_min_votes`` votes. Only votes within ``max_jump_deg`` (15°, widened after frames without an estimate)
of the previous frame's θ count (a print that repeats around the body would otherwise let a frame flip to a copy;
the synthetic lab's texture did, every 90°, until each side direction got its own print). Anchors: frame 0 (θ = 0
by definition) and every frame accepted so far; frame i is matched against frame 0, the latest anchors and a few older ones spread over the session, so that a frame that
sees surface visible before is tied to it directly, and a frame that sees new surface is tied through its
neighbours. Frames without an accepted θ take it interpolated from the accepted ones (held at the ends); θ is
then median-filtered over ``spin_smooth`` frames. Only the rotation about the axis changes: the other five
degrees of freedom, which the geometry fixes, are kept.

Textureless bodies: too few votes anywhere, θ = 0 everywhere (``SpinResult.observable`` False): the spin is
reported as unobservable and the poses are unchanged. A correction above ``max_deg`` in any frame is not applied
(``SpinResult.rejected``): the votes then followed something other than the surface (a lost track).

Pose graph (``spin_links``, ``solve_spin_graph``): θ from a one-parameter pose graph over frame pairs — short links
during motion (pair measurements across a large view change are biased), long links between similar views; see the
comment above ``spin_links``. Mixed estimate (``spin_mixed``, the tracker's default): the chain, with the graph's
increments over fast stretches of the tracked rotation where the chain pooled few votes; see the comment above
``fast_frames``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, NamedTuple

import numpy as np

from service.tracking.geometry import _cross
from service.transforms import X_inv, make_X, so3_exp


@dataclass
class SpinResult:
    is_revolution: bool  # the model's weakest direction is a rotation (body of revolution)
    lam: float  # its normalised eigenvalue λ̂
    axis_O: np.ndarray  # (3,) unit axis a in O (zeros when not a body of revolution)
    point_O: np.ndarray  # (3,) point c on the axis in O
    theta: np.ndarray  # (N,) spin correction (rad) applied to each frame: X_WO ← X_WO S(θ)
    votes: np.ndarray  # (N,) inlier votes of each frame's estimate (0: interpolated)
    observable: bool  # enough texture to measure the spin in some frames
    rejected: bool = False  # the correction exceeded max_deg somewhere and was not applied (θ = 0)
    by_kappa: bool = False  # taken for a body of revolution by the κ separation (a cup, ``kappa_sep_axis``)


def revolution_axis(Q: np.ndarray, N: np.ndarray, tau: float, sep: float = 0.5, k: int = 0
                    ) -> tuple[bool, float, np.ndarray, np.ndarray]:
    """(is_revolution, λ̂, a (3,), c (3,)) of model points Q (M,3) with normals N (M,3) in O (module docstring):
    a body of revolution when λ̂_1 < tau, λ̂_1 ≤ sep · λ̂_2 (one weak direction, not a near-sphere whose weak
    directions mix) and that direction is mostly rotation. ``k`` = 1: the same test on the second weakest
    direction (sep then compares it with the third)."""
    if len(Q) < 20:
        return False, 1.0, np.zeros(3), np.zeros(3)
    lam, U, Di, ctr = _screw_eig(Q, N)
    lam = lam / len(Q)
    lam, U = _split_tie(lam, U, k)
    u = U[:, k]
    if np.sum(u[:3] ** 2) <= 0.5 or lam[k] >= tau or lam[k] > sep * lam[k + 1]:
        return False, float(lam[k]), np.zeros(3), np.zeros(3)
    a, c = _screw_axis(u, Di, ctr)
    return True, float(lam[k]), a, c


def _screw_eig(Q: np.ndarray, N: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Eigen-decomposition of the scaled point-to-plane normal matrix of model points Q (M,3) with normals N (M,3)
    in O (module docstring): λ (6,) ascending (sums over the points, not yet divided by M), U (6,6) its eigenvectors
    over (ω/L, v), the scaling Di (6,6) and the centroid of Q (3,) the screws are taken about."""
    ctr = Q.mean(0)
    P = Q - ctr  # centred: the screw's translation part is then small and well scaled
    J = np.hstack([_cross(P, N), N])
    L = float(np.sqrt(np.mean(np.sum(P**2, 1)))) or 1.0
    Di = np.diag([1 / L, 1 / L, 1 / L, 1.0, 1.0, 1.0])
    lam, U = np.linalg.eigh(Di @ (J.T @ J) @ Di)
    return lam, U, Di, ctr


def _screw_axis(u: np.ndarray, Di: np.ndarray, ctr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis direction a (3,) and a point c (3,) on it, in O, of the screw u (6,) of ``_screw_eig``."""
    xi = Di @ u  # back to (ω, v) in metres: z = D ξ
    w, v = xi[:3], xi[3:]
    a = w / np.linalg.norm(w)
    return a, np.cross(w, v) / float(w @ w) + ctr


def _split_tie(lam: np.ndarray, U: np.ndarray, k: int, rel: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """Eigenpairs (ascending λ, columns of U over (ω/L, v)) with an exact tie at k, k + 1 made definite. A perfect
    extrusion (a cylinder seen without its ends) leaves the spin about its axis and the slide along it both free:
    λ_k = λ_{k+1} = 0 up to rounding, and eigh returns any mix of the two, in either order, depending on the last
    bits of the sums. In a tie (|λ_{k+1} − λ_k| ≤ ``rel`` · λ_max, far below any noise of a measured model) the pair
    is turned so that column k is its most rotational direction; when the other is then mostly a slide, λ_{k+1}
    takes λ_{k+2}: the separation test is about two weak *rotations* (an egg), and a slide is not one."""
    if k + 2 >= len(lam) or abs(lam[k + 1] - lam[k]) > rel * max(abs(lam[-1]), 1e-300):
        return lam, U
    V = U[:, k:k + 2]
    _, E = np.linalg.eigh(V[:3].T @ V[:3])
    U = U.copy()
    U[:, k:k + 2] = V @ E[:, ::-1]
    if np.sum(U[:3, k + 1] ** 2) <= 0.5:
        lam = lam.copy()
        lam[k + 1] = lam[k + 2]
    return lam, U


def profile_axis(Q: np.ndarray, a0: np.ndarray, c0: np.ndarray, deg: int = 4, trunc: float = 0.003
                 ) -> tuple[np.ndarray, np.ndarray, float]:
    """Axis (a, c) of a body of revolution refitted to the radius profile of its points Q (M,3), starting from
    (a0, c0): minimise the mean of min(e², trunc²) over the points, e = r − ρ(h) with r, h the radius and height
    about the axis and ρ the least-squares polynomial of degree ``deg`` in h (Nelder–Mead over two tilts of a and
    two shifts of c). Uses positions only, so it holds where the normals' eigen-axis mixes two weak rotations
    (an egg). Returns (a, c, rms of the truncated residual in m)."""
    from scipy.optimize import minimize

    e1, e2 = plane_basis(a0)

    def unpack(x):
        a = a0 + x[0] * e1 + x[1] * e2
        return a / np.linalg.norm(a), c0 + x[2] * e1 + x[3] * e2

    def cost(x):
        a, c = unpack(x)
        d = Q - c
        h = d @ a
        r = np.linalg.norm(d - h[:, None] * a, axis=1)
        V = np.vander(h / (np.std(h) or 1.0), deg + 1)
        coef, *_ = np.linalg.lstsq(V, r, rcond=None)
        return float(np.mean(np.minimum((r - V @ coef) ** 2, trunc**2)))

    r = minimize(cost, np.zeros(4), method="Nelder-Mead", options=dict(xatol=1e-5, fatol=1e-12, maxiter=2000))
    a, c = unpack(r.x)
    return a, c, float(np.sqrt(r.fun))


def plane_basis(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to the unit vector a and to each other."""
    e1 = np.cross(a, [1.0, 0.0, 0.0])
    if np.linalg.norm(e1) < 0.3:
        e1 = np.cross(a, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(a, e1)


def find_axis(Q: np.ndarray, N: np.ndarray, tau: float, sep: float, profile: str = "mixed", max_rms: float = 0.002
              ) -> tuple[bool, float, np.ndarray, np.ndarray]:
    """(is_revolution, λ̂, a, c) of the model Q, N (M,3): ``revolution_axis``; with ``profile`` "mixed" a model that
    fails the separation test (two nearly equal weak rotations: an egg) or whose weakest direction is a slide with
    a weak rotation next gets its axis refitted to the radius profile (``profile_axis``, from that eigen-axis),
    kept when the profile fits within ``max_rms`` (m); "multi": as "mixed" (the same models kept), the axis of a
    kept model then the best of the refits started from every rotation eigen-axis as well (``profile_starts``);
    "always": every axis is refitted so; "off": the
    eigen-axis alone."""
    ok, lam, a, c = revolution_axis(Q, N, tau, sep)
    if ok and profile != "always":
        return ok, lam, a, c
    if not ok:
        if profile == "off":
            return ok, lam, a, c
        ok, lam, a, c = revolution_axis(Q, N, tau, 1.0)
        if not ok:  # the weakest direction a slide (an egg seen from few sides): the next weakest, a rotation
            ok, lam, a, c = revolution_axis(Q, N, tau, 1.0, k=1)
        if not ok:
            return ok, lam, a, c
    a2, c2, rms = profile_axis(Q, a, c)
    if rms > max_rms:
        return False, lam, np.zeros(3), np.zeros(3)
    if profile == "multi":  # which models are bodies of revolution is decided above, as with "mixed"
        for a0, c0 in profile_starts(Q, N):
            a3, c3, rms3 = profile_axis(Q, a0, c0)
            if rms3 < rms:
                a2, c2, rms = a3, c3, rms3
    return True, lam, a2, c2


def profile_starts(Q: np.ndarray, N: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Starts (a, c) in O for the radius-profile refit (``profile_axis``) of the model Q, N (M,3): the rotation part
    of each eigen-direction of the scaled point-to-plane normal matrix (``revolution_axis``) that is mostly a
    rotation, each at its screw's axis point and at the centroid of Q. The profile cost is not convex in the axis:
    an egg's three rotations are all weak and their eigen-axes mix, so the weakest one may lie anywhere, and a refit
    from it can stop in a local minimum across the body (development egg 1002 with the removed ``track_ransac_thr``:
    from the weakest eigen-axis 1.92 mm RMS, 79° from the long axis; from the centroid or another eigen-axis 1.23 mm,
    9°)."""
    _, U, Di, ctr = _screw_eig(Q, N)
    out = []
    for u in U.T:
        if np.sum(u[:3] ** 2) <= 0.5:
            continue
        a, c = _screw_axis(u, Di, ctr)
        out += [(a, c), (a, ctr)]
    return out


def spin_matrix(a: np.ndarray, c: np.ndarray, theta: float) -> np.ndarray:
    """4x4 rotation by theta (rad) about the line through c with direction a."""
    R = so3_exp(a * theta)
    return make_X(R, c - R @ c)


def interior_features(gray: np.ndarray, depth: np.ndarray, mask: np.ndarray, K: np.ndarray, X_WC: np.ndarray,
                      border_px: int, n_features: int) -> tuple[np.ndarray, np.ndarray | None]:
    """ORB keypoints of a grey image (H,W) uint8 at least ``border_px`` inside the object mask (H,W) with valid depth
    (H,W) metres: (F,3) points in W and (F,32) descriptors (None when there are none). Detected on the crop around
    the mask (same keypoints, less work)."""
    import cv2

    m = mask.astype(np.uint8)
    k = 2 * border_px + 1
    fm = cv2.erode(m, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))) * 255
    vs, us = np.nonzero(fm)
    if len(us) == 0:
        return np.zeros((0, 3)), None
    pad = 24  # ORB's border and patch
    v0, v1 = max(int(vs.min()) - pad, 0), min(int(vs.max()) + pad + 1, gray.shape[0])
    u0, u1 = max(int(us.min()) - pad, 0), min(int(us.max()) + pad + 1, gray.shape[1])
    orb = cv2.ORB_create(nfeatures=n_features, scaleFactor=1.2, nlevels=4, edgeThreshold=9, patchSize=15,
                         fastThreshold=7)
    kps, des = orb.detectAndCompute(np.ascontiguousarray(gray[v0:v1, u0:u1]), np.ascontiguousarray(fm[v0:v1, u0:u1]))
    if des is None or not len(kps):
        return np.zeros((0, 3)), None
    uv = np.array([kp.pt for kp in kps]) + [u0, v0]
    uu = np.clip(np.round(uv[:, 0]).astype(int), 0, depth.shape[1] - 1)
    vv = np.clip(np.round(uv[:, 1]).astype(int), 0, depth.shape[0] - 1)
    z = depth[vv, uu]
    good = z > 0
    if not good.any():
        return np.zeros((0, 3)), None
    Pc = np.stack([(uv[good, 0] - K[0, 2]) / K[0, 0] * z[good], (uv[good, 1] - K[1, 2]) / K[1, 1] * z[good], z[good]], 1)
    return Pc @ X_WC[:3, :3].T + X_WC[:3, 3], des[good]


def _cyl(P_O: np.ndarray, a: np.ndarray, c: np.ndarray, e1: np.ndarray, e2: np.ndarray
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Radius, height and azimuth of points (N,3) about the axis (a, c) with in-plane basis e1, e2 (all in one frame,
    O for the spin votes); m, m, rad in (−π, π] from e1 toward e2."""
    d = P_O - c
    h = d @ a
    x, y = d @ e1, d @ e2
    return np.hypot(x, y), h, np.arctan2(y, x)


def anchor_candidates(anchors: list[int], n_recent: int, n_spread: int) -> tuple[list[int], list[int]]:
    """(older, candidates) of a frame's estimate against the earlier anchors (frame indices, in order): ``older``
    the anchors before the ``n_recent`` latest, frame 0 left out; the candidates (sorted) frame 0, the ``n_recent``
    latest and ``n_spread`` of the older ones spread evenly over them (the chain's drift is checked against frames
    long past)."""
    older = [j for j in anchors[:-n_recent] if j != 0]
    spread = [older[k] for k in np.unique(np.linspace(0, len(older) - 1, n_spread).astype(int))] if older else []
    return older, sorted(set([0] + spread + anchors[-n_recent:]))


def matched_once(match: Callable[[np.ndarray, np.ndarray], np.ndarray]
                 ) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """``match(desc_a, desc_b) -> (M,2)`` that computes each pair once and answers again from memory, keyed by the
    two descriptor arrays' identities (the caller keeps the arrays alive for as long as it uses the matcher)."""
    memo: dict = {}

    def match_once(da: np.ndarray, db: np.ndarray) -> np.ndarray:
        key = (id(da), id(db))
        if key not in memo:
            memo[key] = match(da, db)
        return memo[key]

    return match_once


def spin_votes(pW: np.ndarray, qW: np.ndarray, X_i: np.ndarray, X_j: np.ndarray, a: np.ndarray, c: np.ndarray,
               tol: float, basis: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Spin votes θ (K,) (rad, wrapped to (−π, π]) of matched points p (in frame i, W) and q (in anchor j, W):
    θ with S(θ) q_O = p_O, kept where radius and height about the axis agree within ``tol`` (m) and the radius is
    at least ``tol`` (points on the axis carry no azimuth). ``basis``: ``plane_basis(a)`` when the caller has it (it
    costs more than the votes)."""
    e1, e2 = plane_basis(a) if basis is None else basis
    Xi, Xj = X_inv(X_i), X_inv(X_j)
    pO = pW @ Xi[:3, :3].T + Xi[:3, 3]
    qO = qW @ Xj[:3, :3].T + Xj[:3, 3]
    rp, hp, fp = _cyl(pO, a, c, e1, e2)
    rq, hq, fq = _cyl(qO, a, c, e1, e2)
    ok = (np.abs(rp - rq) < tol) & (np.abs(hp - hq) < tol) & (np.minimum(rp, rq) > tol)
    return np.angle(np.exp(1j * (fp[ok] - fq[ok])))


def vote_mode(theta: np.ndarray, half_width: float) -> tuple[float, int]:
    """(θ, count): the median of the largest set of votes within ±half_width of one another's centre."""
    if len(theta) == 0:
        return 0.0, 0
    t = np.sort(theta)
    t2 = np.concatenate([t, t + 2 * np.pi])  # wrap-around
    j = np.searchsorted(t2, t2[: len(t)] + 2 * half_width, side="right")
    cnt = j - np.arange(len(t))
    k = int(np.argmax(cnt))
    sel = t2[k: j[k]]
    return float(np.angle(np.exp(1j * np.median(sel)))), int(cnt[k])


def spin_closure(feats: list[tuple[np.ndarray, np.ndarray | None]], X_WO: np.ndarray, Q: np.ndarray, N: np.ndarray,
                 *, tau: float, tol: float, inlier_deg: float, min_votes: int, smooth: int, match, sep: float = 0.5,
                 n_recent: int = 3, n_spread: int = 8, max_jump_deg: float = 15.0, profile: str = "off",
                 max_deg: float = 0.0, axis: tuple | None = None, fast: np.ndarray | None = None,
                 theta_fast: np.ndarray | None = None) -> SpinResult:
    """Spin correction θ (N,) of the poses X_WO (N,4,4) of a body of revolution (module docstring) from each
    frame's interior features ``feats[i] = (points (F,3) in W, descriptors (F,32) or None)``
    (``interior_features``); X_WO is not changed (apply with ``apply_spin``). Q (M,3), N (M,3): the final model
    in O. ``match(desc_a, desc_b) -> (M,2)`` pairs descriptors (the tracker's ratio-test matcher). ``axis``: the
    result of ``find_axis`` when already known. ``fast`` (N,) bool with ``theta_fast`` (N,): those frames are not
    voted; each takes the increment of theta_fast since the anchor before its stretch and is an anchor
    (``spin_mixed``)."""
    n = len(X_WO)
    is_rev, lam, a, c = axis if axis is not None else find_axis(Q, N, tau, sep, profile)
    theta = np.zeros(n)
    votes = np.zeros(n, int)
    if not is_rev:
        return SpinResult(False, lam, a, c, theta, votes, False)
    Xc = X_WO.copy()  # corrected poses of the anchors
    basis = plane_basis(a)  # once, for every spin_votes
    anchors = [0]
    half = np.radians(inlier_deg)
    fixed = np.zeros(n, bool)  # frames of fast stretches (spin_mixed)
    entry = None  # the anchor before the current fast stretch
    for i in range(1, n):
        if fast is not None and fast[i]:
            if entry is None:
                entry = anchors[-1]
            theta[i] = theta[entry] + theta_fast[i] - theta_fast[entry]
            fixed[i] = True
            Xc[i] = X_WO[i] @ spin_matrix(a, c, theta[i])
            anchors.append(i)
            continue
        entry = None
        kp, des = feats[i]
        if des is None or len(kp) < min_votes:
            continue
        _, cand = anchor_candidates(anchors, n_recent, n_spread)
        prev = anchors[-1]
        win = np.radians(max_jump_deg) * (1 + (i - prev - 1) / 5)  # wider after frames without an estimate
        th_all = []
        for j in cand:
            kq, dq = feats[j]
            m = match(des, dq)
            if len(m) == 0:
                continue
            th = spin_votes(kp[m[:, 0]], kq[m[:, 1]], X_WO[i], Xc[j], a, c, tol, basis)
            th = theta[prev] + np.angle(np.exp(1j * (th - theta[prev])))
            th = th[np.abs(th - theta[prev]) <= win]
            th_all.append(th)
        t, cnt = vote_mode(np.concatenate(th_all) if th_all else np.zeros(0), half)
        if cnt >= min_votes:
            theta[i] = theta[prev] + np.angle(np.exp(1j * (t - theta[prev])))
            votes[i] = cnt
            Xc[i] = X_WO[i] @ spin_matrix(a, c, theta[i])
            anchors.append(i)
    ok = (votes > 0) | fixed
    ok[0] = True
    observable = int(np.sum(votes > 0)) > 0 or bool(fixed.any())
    idx = np.nonzero(ok)[0]
    full = np.interp(np.arange(n), idx, theta[idx])
    return _finish(full, smooth, max_deg, lam, a, c, votes, observable)


def _finish(full, smooth, max_deg, lam, a, c, votes, observable) -> SpinResult:
    """The spins (n,) median-filtered over ``smooth`` frames, frame 0 held at 0, and the result; a correction above
    ``max_deg`` anywhere is not applied (``rejected``)."""
    if smooth > 1:
        from scipy.ndimage import median_filter

        full = median_filter(full, size=smooth, mode="nearest")
    full[0] = 0.0
    if max_deg > 0 and np.max(np.abs(full)) > np.radians(max_deg):
        # a correction this large means the votes followed something other than the surface (a lost track, whose
        # poses are off by centimetres: development bottle 561 went from 37° to 172° median): not applied
        return SpinResult(True, lam, a, c, np.zeros(len(full)), votes, observable, rejected=True)
    return SpinResult(True, lam, a, c, full, votes, observable)


def apply_spin(X_WO: np.ndarray, res: SpinResult) -> np.ndarray:
    """X_WO (N,4,4) with each frame turned by its θ about the axis: X_WO(i) S(θ_i)."""
    if not res.is_revolution:
        return X_WO.copy()
    return np.stack([X @ spin_matrix(res.axis_O, res.point_O, t) for X, t in zip(X_WO, res.theta)])


# ---- a one-parameter pose graph over the spins (the increments of ``spin_solver`` "mixed" over fast stretches) ----
#
# Per-pair measurements. For frames i, j the mode d_ij of the votes (``spin_votes`` with the uncorrected poses)
# measures θ_i − θ_j. Measured on the development bottle topple 531 with the true poses (every true d_ij = 0):
# consecutive frames are unbiased (±2°, no drift: the sum over the 30 frames of the fast fall is +2°), while links
# three or more frames apart during the fall are biased by +1…+14° (the view changes by 20–50° between them):
# pooled with them, the per-frame chain above follows only half of the tracker's false spin. In slow or static
# stretches the long links are unbiased and stop the random walk of a chain. So the graph keeps, for each frame,
# ``n_short`` links to the nearest earlier frames within ``chain`` frames that have ``min_votes`` votes (the k-th
# weighs vote count / k²), and longer links (frame 0, offsets up to 256) only between similar views moving slowly:
# tracked rotation between the two frames below ``gate_deg`` and at most ``rate_deg`` per frame of separation, and
# √(turn² + d²) below ``gate_deg``, with at least ``long_votes`` votes (weight = vote count). θ (N,) minimises Σ w_ij ρ(θ_i − θ_j − d_ij) with θ_0 = 0
# (ρ Huber, then Cauchy, at ``huber_deg``, IRLS on the normal equations; a weak 1e-3 smoothness between neighbours
# holds frames without links).

GRAPH_OFFSETS = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256)


def spin_links(feats: list[tuple[np.ndarray, np.ndarray | None]], X_WO: np.ndarray, a: np.ndarray, c: np.ndarray, *,
               tol: float, inlier_deg: float, min_votes: int, match, chain: int = 4, gate_deg: float = 3.0,
               n_short: int = 1, rate_deg: float = 0.0, long_votes: int = 0) -> np.ndarray:
    """Links (L,4) rows (i, j, d_ij rad, weight) of the spin graph (comment above) from each frame's interior
    features and the uncorrected poses X_WO (N,4,4) about the axis (a, c) in O."""
    from service.transforms import rotation_angle

    n = len(X_WO)
    half = np.radians(inlier_deg)
    basis = plane_basis(a)  # once, for every spin_votes
    out = []
    for i in range(1, n):
        kp, des = feats[i]
        if des is None or len(kp) < min_votes:
            continue
        n_ch = 0  # short links taken (the nearest earlier frames with enough votes)
        for k in [k for k in GRAPH_OFFSETS if k < i] + [i]:  # ... and frame 0
            j = i - k
            turn = float(np.degrees(rotation_angle(X_WO[i][:3, :3].T @ X_WO[j][:3, :3])))
            long_ok = turn < gate_deg and (rate_deg <= 0 or turn <= rate_deg * k)  # similar views, slow motion
            short = n_ch < n_short and k <= chain
            if not short and not long_ok:
                continue
            kq, dq = feats[j]
            if dq is None:
                continue
            m = match(des, dq)
            if len(m) < min_votes:
                continue
            t, cnt = vote_mode(spin_votes(kp[m[:, 0]], kq[m[:, 1]], X_WO[i], X_WO[j], a, c, tol, basis), half)
            if cnt < min_votes:
                continue
            if short:
                n_ch += 1
                out.append((i, j, t, float(cnt) / n_ch**2))  # the second nearest counts a quarter
                continue
            if np.hypot(turn, np.degrees(t)) >= gate_deg or cnt < long_votes:
                continue
            out.append((i, j, t, float(cnt)))
    return np.array(out, float).reshape(-1, 4)


def solve_spin_graph(n: int, links: np.ndarray, huber_deg: float = 2.0, smooth_w: float = 1e-3, iters: int = 10
                     ) -> np.ndarray:
    """θ (N,) rad minimising Σ w ρ(θ_i − θ_j − d_ij) over the links (L,4) (i, j, d, w), θ_0 = 0; residuals wrapped
    to (−π, π], ρ Huber at huber_deg for ``iters`` IRLS steps, then Cauchy at the same scale for up to ``iters``
    more, plus smooth_w (θ_k − θ_{k−1})² holding frames without links."""
    th = np.zeros(n)
    if n < 2:
        return th
    I, J = links[:, 0].astype(int), links[:, 1].astype(int)
    D, W = links[:, 2], links[:, 3]
    h = np.radians(huber_deg)
    k = np.arange(1, n)
    for it in range(2 * iters):
        r = np.angle(np.exp(1j * (th[I] - th[J] - D)))
        if it < iters:  # Huber from the start, then Cauchy (redescending: a far outlier link stops pulling)
            w = W * np.minimum(1.0, h / np.maximum(np.abs(r), 1e-12))
        else:
            w = W / (1.0 + (r / h) ** 2)
        A = np.zeros((n, n))
        g = np.zeros(n)
        np.add.at(A, (I, I), w)
        np.add.at(A, (J, J), w)
        np.add.at(A, (I, J), -w)
        np.add.at(A, (J, I), -w)
        np.add.at(g, I, -w * r)
        np.add.at(g, J, w * r)
        rs = th[k] - th[k - 1]
        np.add.at(A, (k, k), smooth_w)
        np.add.at(A, (k - 1, k - 1), smooth_w)
        np.add.at(A, (k, k - 1), -smooth_w)
        np.add.at(A, (k - 1, k), -smooth_w)
        np.add.at(g, k, -smooth_w * rs)
        np.add.at(g, k - 1, smooth_w * rs)
        A[0, :] = 0.0
        A[:, 0] = 0.0
        A[0, 0] = 1.0
        g[0] = 0.0
        dx = np.linalg.solve(A, g)
        th += dx
        if np.max(np.abs(dx)) < 1e-6 and it >= iters:
            break
    return th


# ---- mixed estimate: the chain, with the graph's spins over fast weak stretches (``spin_solver`` "mixed") -------
#
# The chain pools, for each frame, the votes of frame 0 and of up to 11 earlier corrected frames: frames whose own
# links are weak (a few votes against each of several anchors, or none against the nearest frame: development bottle
# pivot 553, frames 163-194, 6-13 votes per pair) still get an estimate, which the graph cannot give (links need 6 or
# 12 votes; that stretch drifted 10-14° off). During a fast fall with few interior matches the chain's recent anchors
# are 20-50° of view away and their votes biased, and the graph's short links bridge it. A fast stretch is told by the
# tracked rotation alone: over ``span`` frames more than ``rate_deg`` per frame (development falls 5-12°/frame, slow
# pivots at most 1.7°/frame: the tracker's frame-to-frame jitter of 1-3° averages out over 4 frames), widened by
# ``dilate`` frames each side. A fall the chain follows with many votes (development bottle topple 571: 150-350 pooled
# votes per frame) is left to it (there the graph's short links lag the motion: 2.63° against 1.29° median); so
# only the fast frames where the chain pooled fewer than ``fast_votes`` votes, again widened by ``dilate``, take the
# graph's increments from the frame before their stretch, and the chain runs again with them as anchors. A session
# without such frames gets the chain alone (the graph is not computed).


def fast_frames(X_WO: np.ndarray, span: int = 4, rate_deg: float = 2.0, dilate: int = 4) -> np.ndarray:
    """(N,) bool: frames whose tracked rotation X_WO (N,4,4) over the last ``span`` frames exceeds ``rate_deg`` per
    frame, widened by ``dilate`` frames on each side."""
    from service.transforms import rotation_angle

    n = len(X_WO)
    R = X_WO[:, :3, :3]
    prev = np.maximum(np.arange(n) - span, 0)
    turn = np.degrees(rotation_angle(np.einsum("nji,njk->nik", R, R[prev])))
    return widen(turn > rate_deg * span, dilate)


def widen(f: np.ndarray, d: int) -> np.ndarray:
    """f (N,) bool widened by d frames on each side."""
    out = f.copy()
    for k in range(1, d + 1):
        out[k:] |= f[:-k]
        out[:-k] |= f[k:]
    return out


def spin_mixed(feats: list[tuple[np.ndarray, np.ndarray | None]], X_WO: np.ndarray, Q: np.ndarray, N: np.ndarray, *,
               tau: float, tol: float, inlier_deg: float, min_votes: int, graph_votes: int, smooth: int, match,
               sep: float = 0.5, profile: str = "off", max_deg: float = 0.0, gate_deg: float = 10.0,
               n_short: int = 2, rate_deg: float = 0.5, long_votes: int = 12, fast_span: int = 4,
               fast_rate_deg: float = 2.0, fast_dilate: int = 4, fast_votes: int = 60,
               parts: dict | None = None, axis: tuple | None = None) -> SpinResult:
    """Spin correction like ``spin_closure`` (same axis, cap, result): the chain, with the fast frames where it pooled
    fewer than ``fast_votes`` votes (``fast_frames``; widened) taking the increments of the pose graph
    (``spin_links``, ``solve_spin_graph``; comment above). ``parts``: a dict that receives the intermediate results
    others reuse (keys "axis": ``find_axis``'s result; "theta_g": the graph's solution (N,), when it was computed).
    ``axis``: ``find_axis``'s result when already known (as ``spin_closure``)."""
    n = len(X_WO)
    axis = axis if axis is not None else find_axis(Q, N, tau, sep, profile)
    if parts is not None:
        parts["axis"] = axis
    match_once = matched_once(match)  # the chain runs twice and the graph asks for many of the same pairs
    kw = dict(tau=tau, tol=tol, inlier_deg=inlier_deg, min_votes=min_votes, smooth=smooth, match=match_once,
              sep=sep, profile=profile, max_deg=max_deg, axis=axis)
    fast = fast_frames(X_WO, fast_span, fast_rate_deg, fast_dilate)
    _, _, a, c = axis
    if not axis[0] or not fast[1:].any():
        return spin_closure(feats, X_WO, Q, N, **kw)
    first = spin_closure(feats, X_WO, Q, N, **kw)
    weak = widen(fast & (first.votes < fast_votes), fast_dilate)
    weak[0] = False
    if not weak.any():
        return first
    links = spin_links(feats, X_WO, a, c, tol=tol, inlier_deg=inlier_deg, min_votes=graph_votes,
                       match=match_once, gate_deg=gate_deg, n_short=n_short, rate_deg=rate_deg,
                       long_votes=long_votes)
    theta_g = solve_spin_graph(n, links) if len(links) else np.zeros(n)
    if parts is not None:
        parts["theta_g"] = theta_g.copy()
    return spin_closure(feats, X_WO, Q, N, fast=weak, theta_fast=theta_g, **kw)


def runs(f: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) of the runs of True in f (N,) bool."""
    d = np.diff(np.r_[0, f.astype(int), 0])
    return list(zip(np.nonzero(d == 1)[0], np.nonzero(d == -1)[0]))


# ---- the body's twist smoothed instead of the correction (``spin_twist_smooth``) --------------------------------
#
# The chain's per-frame correction θ_i is the difference between the texture's spin and the tracker's: the tracker's
# rotation about the axis jitters from frame to frame (development bottle pivots 911, 553: the error about the axis of
# the uncorrected poses moves by 1–3° between consecutive frames while the bottle rests), so θ must carry that jitter,
# and a median filter over θ (``spin_smooth``) removes it again wherever the votes scatter. What changes slowly is the
# body's own twist: the pivots tilt the standing bottle by 13° and back while its rotation about its axis changes by
# at most 1.5° over 10 frames (ground truth of the development pivots, read by the diagnosis only), whereas the
# per-frame vote modes scatter by ±2–5° with 20–60 votes and, against anchors 10° of tilt away, are biased by up
# to −12°. So the filter is put on the corrected twist: τ_i = τ(R_0ᵀ R_i) + θ_i, with τ(R) the twist angle of R
# about a (swing–twist decomposition, R = swing · twist; a right factor S(θ) about a adds θ to it exactly), is
# median-filtered over ``size`` frames and θ_i ← τ̃_i − τ(R_0ᵀ R_i). A median keeps steps and monotone ramps (a
# body that rolls on, or a spin that settles at a new value), so a twist that really changes is not flattened.


def twist_angles(X_WO: np.ndarray, a: np.ndarray) -> np.ndarray:
    """(N,) rad: the twist about the unit axis a (3,) in O of each frame's rotation relative to frame 0,
    R_0ᵀ R_i = swing · twist (swing–twist decomposition), unwrapped along the frames."""
    from service.transforms import mat_to_quat

    q = mat_to_quat(np.einsum("ji,njk->nik", X_WO[0, :3, :3], X_WO[:, :3, :3]))
    return np.unwrap(2.0 * np.arctan2(q[:, 1:] @ a, q[:, 0]))


def smooth_twist(res: SpinResult, X_WO: np.ndarray, size: int, max_deg: float = 0.0) -> SpinResult:
    """``res`` with its correction θ (N,) replaced by the median-filtered corrected twist of the poses X_WO (N,4,4)
    (comment above): θ_i ← median_size(τ + θ)_i − τ_i, τ = ``twist_angles``; frame 0 held at 0; a result above
    ``max_deg`` anywhere is not applied (``rejected``, as in the chain). Unchanged when ``size`` ≤ 1, when the body
    is not a body of revolution, or when the correction was not measured or was rejected."""
    if size <= 1 or not res.is_revolution or not res.observable or res.rejected:
        return res
    from scipy.ndimage import median_filter

    tau = twist_angles(X_WO, res.axis_O)
    theta = median_filter(tau + res.theta, size=size, mode="nearest") - tau
    theta[0] = 0.0
    return _finish(theta, 1, max_deg, res.lam, res.axis_O, res.point_O, res.votes, res.observable)


# ---- bodies of revolution seen in part: the axis test normalised by what the model covers (``spin_arc_tau``) -----
#
# ``revolution_axis`` scales a rotation by L, the RMS distance of the model points from their centroid, so λ̂_1 of a
# model that covers only a short band of a body of revolution is large even when its normals are as consistent with
# the axis as a full model's: the development bottle pivots 940, 941, 943, 944, whose models cover 82-89 mm of the
# 200 mm bottle seen from one side (the occluder hides the rest), have λ̂_1 = 0.031-0.036 against 0.005-0.016 for
# the bottles covered over 177-198 mm, with the same normals. The spin about the axis moves every point p by the arc
# |a × (p − c)| per radian; the fraction of that motion the surface sees is
#     κ = Σ (n · (a × (p − c)))² / Σ |a × (p − c)|²,
# the mean squared sine of the normals' angle out of the meridian planes (0 for an exact surface of revolution,
# whatever part of it is covered). Measured on the development models (stored tracks): bottles full or partial
# 0.032-0.071, mugs 0.030-0.051, egg 512 0.033; l-blocks, milk cartons, baking boxes 0.116-0.253, prism 805 (whose
# weakest direction is a rotation about a far line, i.e. nearly a slide) 0.72. The test below takes a model that the
# λ̂ test refuses for a body of revolution when its weakest direction is still one clear rotation (λ̂_1 ≤ sep · λ̂_2,
# mostly rotation), κ < ``arc_tau`` and its radius profile fits within ``max_rms`` (positions only, ``profile_axis``):
# on the development models it admits exactly the four partial bottles and no box, prism, l-block or mug that the
# λ̂ test refused.

def arc_score(Q: np.ndarray, N: np.ndarray, a: np.ndarray, c: np.ndarray) -> float:
    """κ (comment above) of the model points Q (M,3) with unit normals N (M,3) about the axis line (a, c)."""
    t = np.cross(a, Q - c)
    den = float(np.sum(t**2))
    return float(np.sum(np.sum(N * t, 1) ** 2) / den) if den > 0 else 1.0


def partial_tau(Q: np.ndarray, N: np.ndarray, tau: float, sep: float, arc_tau: float, max_rms: float = 0.002
                ) -> float:
    """The λ̂ threshold to use for the model Q, N (M,3) (comment above): ``tau`` unless the model fails the λ̂ test
    but its weakest direction passes the separation, rotation, arc (κ < ``arc_tau``) and profile (``max_rms`` m)
    tests; then a value just above its λ̂_1, so that ``find_axis`` takes its eigen-axis. ``arc_tau`` ≤ 0: ``tau``."""
    if arc_tau <= 0 or len(Q) < 20:
        return tau
    ok, lam, _, _ = revolution_axis(Q, N, tau, sep)
    if ok:
        return tau
    ok, lam, a, c = revolution_axis(Q, N, np.inf, sep)  # the same axis without the λ̂ threshold
    if not ok or arc_score(Q, N, a, c) >= arc_tau:
        return tau
    if profile_axis(Q, a, c)[2] > max_rms:
        return tau
    return float(np.nextafter(lam, np.inf))


# ---- flat faces are not a surface of revolution (``spin_flat_kappa``) ---------------------------------------------
#
# The λ̂ test scales a rotation by L, the RMS distance of the model points from their centroid, so a long prism is
# taken for a body of revolution about its long axis: its side faces' residual under that spin is of the order of its
# section, small against L (a 300 × 60 × 60 mm box: λ̂ 0.015-0.020; development milk_carton topple 1490: λ̂ 0.025,
# axis 13° from the carton's long axis). What tells a prism from a body of revolution is where its normals point.
# On a surface of revolution every normal lies in the meridian plane through its point (the plane of the axis and
# the point): turned about the axis, the surface slides in itself. On a flat face the normal is one direction while
# the points sweep an arc about any axis, so the normals leave the meridian planes by an angle ψ that grows to the
# face's edges (tan ψ = s / h, s along the face from the foot of the perpendicular from the axis, h that
# perpendicular). The score is the existing κ (``arc_score``) about the axis the closure would use:
#     κ = Σ (n · (a × (p − c)))² / Σ |a × (p − c)|²,
# the r²-weighted mean of |n_⊥|² sin² ψ: ≈ 0 for a surface of revolution, whatever part of it is covered and
# whatever its profile; for a square prism about its centre line ∫ s² ds / ∫ (h² + s²) ds = 1/4 over the side faces
# (less where end caps, whose normals are along the axis, dilute it; more about an axis off the prism's centre
# line). A model that passes the axis test with κ ≥ ``spin_flat_kappa`` is not taken for a body of revolution: its
# surface would see the spin the closure is about to apply, so the spin is not the free direction the closure
# assumes.

def flat_faced(Q: np.ndarray, N: np.ndarray, axis: tuple, kappa_max: float) -> bool:
    """True when ``axis`` = (is_revolution, λ̂, a, c) (``find_axis`` of the model points Q (M,3) with unit normals
    N (M,3), in O) takes the model for a body of revolution but its normals leave the meridian planes about (a, c)
    by κ ≥ ``kappa_max`` (``arc_score``; comment above): flat faces, a prism. False when ``kappa_max`` ≤ 0 or the
    model was not taken for a body of revolution."""
    ok, _, a, c = axis
    return bool(kappa_max > 0 and ok and arc_score(Q, N, a, c) >= kappa_max)


# ---- a short open cup: its tilts nearly as weak as its spin (``spin_sep_kappa``) ----------------------------------
#
# The λ̂ test and the separation test (λ̂₁ ≤ ``spin_sep`` · λ̂₂, there to refuse a near-sphere whose weak rotations
# mix) both judge a rotation by the residual it leaves, scaled by L, the RMS distance of the model points from their
# centroid. A cup is short and open: no base is seen (it stands on the table, whose points are dropped), its rim is
# 6 mm wide, and its walls are about as tall as they are wide, so a tilt about a horizontal line through the centroid
# moves the walls only by their height from the centroid and leaves a residual close to the spin's (development mug
# pivots 1818, 1819: λ̂₁ 0.033, 0.030 for the spin, λ̂ 0.040, 0.058 for the next rotation, a tilt; both tests fail).
# What still tells the spin apart is where the normals point (κ, ``arc_score``, comment above ``flat_faced``): about
# the cup's axis they lie in the meridian planes (κ 0.034-0.035), about the tilt's eigen-axis they do not (0.111,
# 0.130). A near-sphere has small κ about every axis; a box has large κ about every axis. So the separation can be
# judged by κ instead of λ̂: the weakest direction is a rotation with κ₁ < ``arc_tau``, its radius profile fits within
# ``max_rms`` (``profile_axis``, as ``partial_tau``), and the next weakest rotation eigen-direction has κ at least
# ``ratio`` · κ₁. Then the model is taken for a body of revolution about that eigen-axis.

def kappa_sep_axis(Q: np.ndarray, N: np.ndarray, ratio: float, arc_tau: float, max_rms: float = 0.002
                   ) -> tuple[bool, float, np.ndarray, np.ndarray]:
    """(is_revolution, λ̂₁, a, c) of the model points Q (M,3) with unit normals N (M,3) in O by the κ separation
    (comment above): True with the weakest eigen-direction's axis when it is mostly a rotation, κ₁ < ``arc_tau``,
    its radius profile fits within ``max_rms`` (m) and the next weakest direction that is mostly a rotation has
    κ ≥ ``ratio`` · κ₁ (none: refused). ``ratio`` ≤ 0 or ``arc_tau`` ≤ 0: always refused (the option off)."""
    def refused(lam1: float) -> tuple[bool, float, np.ndarray, np.ndarray]:
        return False, lam1, np.zeros(3), np.zeros(3)

    if ratio <= 0 or arc_tau <= 0 or len(Q) < 20:
        return refused(1.0)
    lam, U, Di, ctr = _screw_eig(Q, N)
    lam = lam / len(Q)
    rot = np.sum(U[:3] ** 2, 0) > 0.5
    if not rot[0]:
        return refused(float(lam[0]))
    a, c = _screw_axis(U[:, 0], Di, ctr)
    k1 = arc_score(Q, N, a, c)
    nxt = [k for k in range(1, len(lam)) if rot[k]]
    if k1 >= arc_tau or not nxt:
        return refused(float(lam[0]))
    a2, c2 = _screw_axis(U[:, nxt[0]], Di, ctr)
    if arc_score(Q, N, a2, c2) < ratio * k1 or profile_axis(Q, a, c)[2] > max_rms:
        return refused(float(lam[0]))
    return True, float(lam[0]), a, c
