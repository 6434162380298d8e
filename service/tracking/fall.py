"""Spin of a body of revolution through a topple: no turn about its own axis while it falls (and through the tilts of
a pivot: ``pivot_runs``, ``pivot_bridge`` at the end of the module).

Physics. A body of revolution (symmetry axis a) tipping over on the table is acted on by gravity, which passes
through its centre of mass on the axis, by the table's normal force at the contact on the rim of its base, and by
the end effector's contact force. The normal of a surface of revolution lies in the meridian plane through the
point, so every normal force line meets the axis (or is parallel to it): none has a moment about a. With the
friction moments small, Euler's equation for a symmetric body about its axis, I_a dω_a/dt = τ_a ≈ 0, keeps the
spin rate ω·a constant through the topple, and it is 0 for a body at rest before the push. Measured on the lab's
bottle topples (development seeds 521, 531, 571, 850; ground truth read by the diagnosis only): the spin about the
axis over the whole topple (about 35 frames, the axis turning 90°) is 0.6-2°, while the tracker adds a false
spin of 0.5-0.8° per degree of tilt while the bottle starts to tip (about 1° of tilt per frame) and up to
4°/frame in the fast fall (development 531: −27°, 850: +41° by the landing), which the texture (``spin``: chain,
graph) follows only partly (531: 19° of the 27°, 850: 26° of 41°; docs/tracking-findings.md "Fall without spin").

Topple frames (``topple_frames``). With the tracked poses X_WO(i) and the axis a in O, τ(i) = the angle of
R_WO(i) a from the vertical (0° standing, 90° lying), median-filtered over 5 frames. A frame moves when τ changes by
more than ``rate_deg`` per frame over ±``half`` frames; runs of moving frames (gaps of ≤ ``gap`` frames closed)
whose τ changes by at least ``min_deg`` in all are topples (a pivot tilts the bottle 10-20° and back: not one).
Each is trimmed to the frames after τ first leaves its start value by ``edge_deg`` up to the first frame within
``edge_deg`` of its end value (the landing): after the landing the body may roll on the table, a real spin.

No-twist increments. With ψ_i the twist about a of the tracked frame-to-frame rotation R_WO(i−1)ᵀ R_WO(i)
(``twist_steps``: ψ = 2 atan2(q_v·a, q_w) of its quaternion, the same for either order of the swing-twist split),
the corrected poses X_WO(i) S(θ_i) of ``spin`` have the twist ψ_i + θ_i − θ_{i−1}, which is 0 for
θ_i = θ_{i−1} − ψ_i. Over a topple's frames the spin correction takes these increments from the frame before it
(``spin_closure`` with those frames as anchors, as the mixed estimate does with the graph's), the chain continuing
from them after the landing.

Guard. The increments carry the tracker's other errors (a tilt error of a few degrees turns part of each 10-15°
fall step into twist: 1-2° over a topple on the development bottles), while the texture, where it follows the fall,
is better. So the default estimate (``spin_mixed``) is kept unless its spin change over a topple differs from the
no-twist change by more than ``tol_deg``: development 521 and 571, 0.5° and 2.2° apart (texture kept); 531, 850,
881 4-6° apart (the texture lagged).
"""

from __future__ import annotations

import numpy as np

from service.tracking.spin import SpinResult, fast_frames, matched_once, runs, solve_spin_graph, \
    spin_closure, spin_links, spin_mixed, widen
from service.transforms import mat_to_quat


def twist_steps(X_WO: np.ndarray, a: np.ndarray) -> np.ndarray:
    """(N,) twist (rad) about the body axis a (3,) (in O) of each frame-to-frame rotation R_WO(i−1)ᵀ R_WO(i) of the
    poses X_WO (N,4,4); 0 for frame 0."""
    R = X_WO[:, :3, :3]
    if len(R) < 2:
        return np.zeros(len(R))
    q = mat_to_quat(np.einsum("nji,njk->nik", R[:-1], R[1:]))
    psi = 2.0 * np.arctan2(q[:, 1:] @ a, q[:, 0])
    return np.r_[0.0, np.angle(np.exp(1j * psi))]


def axis_tilt_deg(X_WO: np.ndarray, a: np.ndarray) -> np.ndarray:
    """(N,) angle (deg) of the body axis a (in O) from the vertical of W, in [0, 90]."""
    aW = np.einsum("nij,j->ni", X_WO[:, :3, :3], a)
    return np.degrees(np.arccos(np.clip(np.abs(aW[:, 2]) / np.linalg.norm(aW, axis=1), 0.0, 1.0)))


def topple_frames(X_WO: np.ndarray, a: np.ndarray, *, rate_deg: float = 0.4, min_deg: float = 45.0,
                  edge_deg: float = 1.0, half: int = 3, smooth: int = 5, gap: int = 3) -> np.ndarray:
    """(N,) bool: the frames of the topples of the poses X_WO (N,4,4) of a body with axis a (3,) in O (module
    docstring): the axis' angle from the vertical changes by more than ``rate_deg`` per frame (over ±``half``
    frames) and by at least ``min_deg`` over the run; each run trimmed to [leaving its start by ``edge_deg``,
    reaching its end within ``edge_deg``]. Frame 0 is never one."""
    from scipy.ndimage import median_filter

    n = len(X_WO)
    out = np.zeros(n, bool)
    if n < 3:
        return out
    tau = median_filter(axis_tilt_deg(X_WO, a), size=smooth, mode="nearest")
    idx = np.arange(n)
    d = tau[np.minimum(idx + half, n - 1)] - tau[np.maximum(idx - half, 0)]
    merged: list[list[int]] = []
    for s, e in runs(np.abs(d) > rate_deg * 2 * half):
        if merged and s - merged[-1][1] <= gap:
            merged[-1][1] = e
        else:
            merged.append([s, e])
    for s, e in merged:
        lo, hi = max(s - half, 0), min(e - 1 + half, n - 1)
        if abs(tau[hi] - tau[lo]) < min_deg:
            continue
        seg = np.arange(lo, hi + 1)
        away = np.nonzero(np.abs(tau[seg] - tau[lo]) > edge_deg)[0]
        near = np.nonzero(np.abs(tau[seg] - tau[hi]) <= edge_deg)[0]
        s2 = seg[away[0]] - 1 if len(away) else s
        e2 = seg[near[0]] if len(near) else e - 1
        out[max(s2, 1):e2 + 1] = True
    return out


def spin_fall(feats: list[tuple[np.ndarray, np.ndarray | None]], X_WO: np.ndarray, Q: np.ndarray, N: np.ndarray, *,
              tau: float, tol: float, inlier_deg: float, min_votes: int, graph_votes: int, smooth: int, match,
              sep: float = 0.5, profile: str = "off", max_deg: float = 0.0, gate_deg: float = 10.0, n_short: int = 2,
              rate_deg: float = 0.5, long_votes: int = 12, fast_span: int = 4, fast_rate_deg: float = 2.0,
              fast_dilate: int = 4, fast_votes: int = 60, fall_rate_deg: float = 0.4, fall_min_deg: float = 45.0,
              fall_edge_deg: float = 1.0, fall_tol_deg: float = 3.0, axis: tuple | None = None
              ) -> tuple[SpinResult, np.ndarray]:
    """(spin correction, (N,) bool frames that took the no-twist increments) for the poses X_WO (N,4,4) of a body of
    revolution with model Q, N (M,3) in O and interior features ``feats`` (as ``spin_mixed``, whose settings the
    other arguments are): ``spin_mixed``'s estimate, except over the topples (``topple_frames``) where its spin
    change differs from the no-twist change by more than ``fall_tol_deg``: those take the no-twist increments and
    the other weak fast frames the graph's, as in ``spin_mixed`` (module docstring). No topple, or none refused by
    the guard:
    ``spin_mixed``'s result itself. ``axis``: ``find_axis``'s result when already known (as ``spin_mixed``)."""
    n = len(X_WO)
    parts: dict = {}  # spin_mixed's graph solution, reused below (the same links: same poses, axis and settings)
    match_once = matched_once(match)  # the default estimate and the one with the topples share the pairs

    base = spin_mixed(feats, X_WO, Q, N, tau=tau, tol=tol, inlier_deg=inlier_deg, min_votes=min_votes,
                      graph_votes=graph_votes, smooth=smooth, match=match_once, sep=sep, profile=profile,
                      max_deg=max_deg, gate_deg=gate_deg, n_short=n_short, rate_deg=rate_deg, long_votes=long_votes,
                      fast_span=fast_span, fast_rate_deg=fast_rate_deg, fast_dilate=fast_dilate,
                      fast_votes=fast_votes, parts=parts, axis=axis)
    none = np.zeros(n, bool)
    if not base.is_revolution or base.rejected:
        return base, none
    axis = parts["axis"]  # the axis spin_mixed fitted (the multi-start profile fit is the costly part)
    _, _, a, c = axis
    kw = dict(tau=tau, tol=tol, inlier_deg=inlier_deg, min_votes=min_votes, smooth=smooth, match=match_once,
              sep=sep, profile=profile, max_deg=max_deg, axis=axis)

    fall = topple_frames(X_WO, a, rate_deg=fall_rate_deg, min_deg=fall_min_deg, edge_deg=fall_edge_deg)
    if not fall.any():
        return base, none
    psi = twist_steps(X_WO, a)
    prior = spin_closure(feats, X_WO, Q, N, fast=fall, theta_fast=np.cumsum(np.where(fall, -psi, 0.0)), **kw)
    used = np.zeros(n, bool)
    for s, e in runs(fall):  # the guard: the texture kept where it agrees with the no-twist change
        d = (prior.theta[e - 1] - prior.theta[s - 1]) - (base.theta[e - 1] - base.theta[s - 1])
        if abs(d) > np.radians(fall_tol_deg):
            used[s:e] = True
    if not used.any():
        return base, none
    weak = np.zeros(n, bool)
    fast = fast_frames(X_WO, fast_span, fast_rate_deg, fast_dilate)
    if fast[1:].any():
        first = prior if np.array_equal(used, fall) else \
            spin_closure(feats, X_WO, Q, N, fast=used, theta_fast=np.cumsum(np.where(used, -psi, 0.0)), **kw)
        weak = widen(fast & (first.votes < fast_votes), fast_dilate) & ~used
        weak[0] = False
    inc = np.where(used, -psi, 0.0)
    if weak.any():
        theta_g = parts.get("theta_g")
        if theta_g is None:
            links = spin_links(feats, X_WO, a, c, tol=tol, inlier_deg=inlier_deg, min_votes=graph_votes,
                               match=match_once, gate_deg=gate_deg, n_short=n_short, rate_deg=rate_deg,
                               long_votes=long_votes)
            theta_g = solve_spin_graph(n, links) if len(links) else np.zeros(n)
        inc = np.where(weak, np.r_[0.0, np.diff(theta_g)], inc)
    res = spin_closure(feats, X_WO, Q, N, fast=used | weak, theta_fast=np.cumsum(inc), **kw)
    return res, used



# ---- the tilts of a pivot: no spin either (``spin_pivot_deg``) ------------------------------------------------------
#
# The same physics holds while the end effector tilts a standing body of revolution onto the rim of its base and lets
# it back (a pivot): gravity acts on the axis, the table's normal force at the lowest point of the rim lies in the
# vertical plane through the axis, and the effector's normal force on a surface of revolution meets the axis, so only
# friction moments turn the body about a (development bottle pivots 1468-1475, ground truth read by the diagnosis
# only: at most 3.7° of twist over a tilt of 9-23°, most of it as the contact starts). The tracked poses add far more there:
# ICP cannot see the spin and the texture's votes between views tilted 10-15° apart are biased, so the loop turns the
# body by up to 13° about its axis in a tilt and the chain (``spin``) follows or adds its own drift (up to 11°), which
# goes away when the body stands upright again and the views of the frames before the tilt return. So over each tilt
# of the tracked poses that leaves the standing direction of the axis and comes back to it, the correction keeps the
# tracked rotation free of twist about a (``twist_steps``: θ_i = θ_{s−1} − Σ ψ), starting from the upright frame
# before the tilt, and the difference to the correction of the upright frame after it (the twist the friction did
# add, and what the no-twist sum cannot know) is spread along the tilt in proportion to the tilt's progress
# (cumulative change of the axis' angle): a bridge between the two upright ends, which the texture measures against
# the views before the tilt. A tilt where the correction already stays within ``tol_deg`` of the bridge keeps it.


def pivot_runs(X_WO: np.ndarray, a: np.ndarray, min_deg: float, edge_deg: float = 1.0, max_deg: float = 45.0,
               stand_deg: float = 15.0, smooth: int = 5) -> list[tuple[int, int]]:
    """The tilts of a pivot in the poses X_WO (N,4,4) of a body with axis a (3,) in O standing on its base at frame 0
    (axis within ``stand_deg`` of the vertical of W; else none: a lying body may be rolling): runs [s, e) of frames whose
    axis direction in W (angle from frame 0's, median-filtered over ``smooth`` frames) is more than ``edge_deg`` from
    frame 0's, reaching at least ``min_deg`` and less than ``max_deg`` (a topple is not one), and back within
    ``edge_deg`` before the last frame or still tilted at the last one (e = N); s ≥ 1."""
    from scipy.ndimage import median_filter

    n = len(X_WO)
    if n < 3 or axis_tilt_deg(X_WO[:1], a)[0] > stand_deg:
        return []
    u = np.einsum("nij,j->ni", X_WO[:, :3, :3], a / np.linalg.norm(a))
    alpha = np.degrees(np.arccos(np.clip(u @ u[0], -1.0, 1.0)))
    alpha = median_filter(alpha, size=smooth, mode="nearest")
    return [(s, e) for s, e in runs(alpha > edge_deg) if s >= 1 and min_deg <= alpha[s:e].max() < max_deg]


def pivot_bridge(theta: np.ndarray, X_WO: np.ndarray, a: np.ndarray, tilts: list[tuple[int, int]], tol_deg: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(θ (N,), (N,) bool frames changed): the spin correction θ (rad) of the poses X_WO (N,4,4) with each tilt
    [s, e) of ``tilts`` bridged without twist about a (3,) in O (comment above): θ_i = θ_{s−1} − Σ_{k=s..i} ψ_k + w_i D,
    D making frame e (upright again) keep θ_e, w_i the fraction of the tilt's axis motion done by frame i; a tilt
    still on at the last frame (e = N) has no upright end: D = 0. A tilt whose θ stays within ``tol_deg`` of its
    bridge is left as it is."""
    theta = theta.copy()
    used = np.zeros(len(theta), bool)
    psi = twist_steps(X_WO, a)
    u = np.einsum("nij,j->ni", X_WO[:, :3, :3], a / np.linalg.norm(a))
    n = len(theta)
    for s, e in tilts:
        f = min(e, n - 1)  # the upright frame after the tilt (the last frame when it is still tilted there)
        free = theta[s - 1] - np.cumsum(psi[s:f + 1])  # frames s..f, no twist from the upright frame s−1
        step = np.degrees(np.arccos(np.clip(np.einsum("ni,ni->n", u[s - 1:f], u[s:f + 1]), -1.0, 1.0)))
        w = np.cumsum(step) / step.sum() if step.sum() > 0 else np.linspace(1.0 / (f - s + 1), 1.0, f - s + 1)
        bridge = free + w * (theta[f] - free[-1]) if e < n else free
        if np.max(np.abs(bridge[:e - s] - theta[s:e])) > np.radians(tol_deg):
            theta[s:e] = bridge[:e - s]
            used[s:e] = True
    return theta, used
