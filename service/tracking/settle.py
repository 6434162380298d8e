"""Re-localisation of the settled object after a fast-motion gap (a topple's landing), landing frames backwards.

A topple ends with 1–3 frames turning 14–16° each (440 °/s) while the occluder may hide most of the object. The
tracking loop follows the fall from the previous poses, which lag (development milk_carton topple 820: 9.6° at the
last frame before the landing), and after the landing it carries that error on: the settled object is then tracked
at a consistent wrong pose (keyframes taken there put the wrong pose into the model, so every later frame fits).
The frames after the landing are easy (the object lies still, many pixels), so:

1. Detection (online, after frame i is tracked): the last ``settle_still_frames`` tracked frames up to i are
   consecutive and still (steps below ``settle_still_deg`` / ``settle_still_dist``) and, within ``settle_window``
   frames before them, a step turned faster than ``settle_fast_deg`` per frame (or a frame was lost while turning
   faster than half that). The gap starts at g0: walking back from the fast step while the steps turn more than
   ``settle_fall_deg`` per frame (the fall).
   Only a track shown wrong is questioned: the model of all keyframes so far, placed with frame i's tracked pose,
   must cover pixels where the frame sees the table or background, or lie through the table
   (``landing.pose_consistent``); else nothing changes.
2. Re-localisation of frame i against the model of the keyframes taken before g0 (the poses before the fall are
   good): starts are the tracked pose, the pose at which the last pre-gap step's screw brings the model to the
   table (``landing.land_on_table``), and the object resting on a face of the pre-gap model's convex hull
   (``resting_rotations``: each large hull face turned to face down, rotated about the vertical in steps of
   ``settle_yaw_deg``, lowered onto the table). Each resting start is placed horizontally by ``slide_search``
   (coverage of the frame's points by the model minus 2 × the fraction of model points the frame sees through,
   on a ±16 cm grid of 4 cm) and the ``settle_icp`` best are refined by ICP; after every ICP a finer slide search
   (the slide along a face that point-to-plane ICP cannot see) and ICP again. A result must be consistent
   (``landing.pose_consistent``: not through the table, not covering pixels where the frame sees the table or
   background). Score = inlier fraction − 0.02 · RMSE/mm + ``settle_w_feat`` · (ORB matches against the pre-gap
   keyframes that agree with the pose within 1 cm, capped at 50)/50 − 2 × the seen-through fraction.
3. When the best pose differs from the tracked one (> ``settle_min_deg`` or > ``settle_min_dist``), scores
   ``settle_margin`` more than the tracked pose evaluated against the same model, and at least ``settle_min_frac``
   of the frame's points are its inliers, the keyframes from g0 on are
   dropped, frame i takes the re-localised pose and the tracking loop goes on from it (it becomes a keyframe: it
   is far from every remaining one).
4. After the loop (``tracker._settle_backward``): the frames g0…i−1 are registered backwards from frame i (start: the next frame's
   pose, and the constant-velocity prediction backwards), against the model of the whole loop; each keeps the
   better consistent fit of its forward and backward registrations, and a frame with neither is marked lost
   (interpolated). The final pass then re-registers them like every frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.transforms import X_inv, make_X, pose_distance


@dataclass
class Landing:
    g0: int  # first frame of the fast stretch (its poses are suspect)
    i: int  # the settled frame that was re-localised
    X_old: np.ndarray  # (4,4) its tracked pose before
    X_new: np.ndarray  # (4,4) the re-localised pose
    score_old: float
    score_new: float
    adopted: bool


def find_gap(X: np.ndarray, tracked: np.ndarray, i: int, still_frames: int, still_deg: float, still_dist: float,
             fast_deg: float, fall_deg: float, window: int, after: int = 0) -> int | None:
    """g0 (first frame of the fast stretch) when frame i ends a still run of ``still_frames`` tracked consecutive
    frames preceded, within ``window`` frames, by a fast step ending after frame ``after`` (a gap handled before
    ends there); else None. X (N,4,4) poses so far, tracked (N,)."""
    j0 = i - still_frames + 1
    if j0 < 2 or not tracked[j0:i + 1].all():
        return None
    for j in range(j0 + 1, i + 1):
        dt, da = pose_distance(X[j - 1], X[j])
        if da > still_deg or dt > still_dist:
            return None
    # steps between consecutive tracked frames before the still run (rate per frame)
    fast = None
    lo = max(1, j0 - window, after + 1)
    for j in range(j0, lo - 1, -1):  # step ending at frame j (j0 included: the step onto the still pose)
        if not tracked[j]:
            continue
        k = j - 1
        while k >= 0 and not tracked[k]:
            k -= 1
        if k < 0:
            break
        da = pose_distance(X[k], X[j])[1] / (j - k)
        if da > fast_deg or (j - k > 1 and da > 0.5 * fast_deg):
            fast = j
            break
    if fast is None:
        return None
    g0 = fast - 1
    while g0 > 1:
        k = g0 - 1
        if not (tracked[g0] and tracked[k]) or pose_distance(X[k], X[g0])[1] > fall_deg:
            g0 -= 1
        else:
            break
    return g0


def resting_rotations(Q_O: np.ndarray, yaw_deg: float, min_area_frac: float = 0.05, merge_deg: float = 15.0
                      ) -> list[np.ndarray]:
    """Rotations R_WO (3,3) that put the object on a face of the convex hull of Q_O (M,3): for every group of hull
    facets with normals within ``merge_deg`` whose area is at least ``min_area_frac`` of the hull's, the rotation
    turning its (area-weighted) outward normal to −z, then turned about the vertical in steps of ``yaw_deg``."""
    from scipy.spatial import ConvexHull

    if len(Q_O) < 10:
        return []
    h = ConvexHull(Q_O)
    nrm = h.equations[:, :3]
    tri = Q_O[h.simplices]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    order = np.argsort(-area)
    used = np.zeros(len(area), bool)
    groups = []
    cmax = np.cos(np.radians(merge_deg))
    for f in order:
        if used[f]:
            continue
        sel = (~used) & (nrm @ nrm[f] > cmax)
        used |= sel
        n = (area[sel, None] * nrm[sel]).sum(0)
        groups.append((area[sel].sum(), n / np.linalg.norm(n)))
    total = area.sum()
    out = []
    for a, n in groups:
        if a < min_area_frac * total:
            continue
        R0 = _align(n, np.array([0.0, 0.0, -1.0]))
        for psi in np.radians(np.arange(0.0, 360.0, yaw_deg)):
            c, s = np.cos(psi), np.sin(psi)
            out.append(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]) @ R0)
    return out


def _align(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation (3,3) taking unit vector a to unit vector b."""
    v = np.cross(a, b)
    c = float(a @ b)
    if np.linalg.norm(v) < 1e-9:
        if c > 0:
            return np.eye(3)
        p = np.array([1.0, 0, 0]) if abs(a[0]) < 0.9 else np.array([0, 1.0, 0])
        p = p - (p @ a) * a
        p /= np.linalg.norm(p)
        return 2 * np.outer(p, p) - np.eye(3)
    V = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + V + V @ V / (1 + c)


def resting_pose(R_WO: np.ndarray, Q_O: np.ndarray, P_W: np.ndarray, table_height: float) -> np.ndarray:
    """Pose (4,4) with rotation R_WO whose model Q_O (M,3) touches the table from above, its centroid above the
    centroid of the frame's points P_W (N,3) horizontally."""
    Qw = Q_O @ R_WO.T
    t = np.empty(3)
    t[:2] = P_W[:, :2].mean(0) - Qw[:, :2].mean(0)
    t[2] = table_height - Qw[:, 2].min()
    return make_X(R_WO, t)


def screen(P_W: np.ndarray, X_WO: np.ndarray, tree, radius: float = 0.01) -> float:
    """Fraction of P_W (N,3) within ``radius`` of the model (KD-tree over its points in O) placed with X_WO."""
    Xi = X_inv(X_WO)
    d, _ = tree.query(P_W @ Xi[:3, :3].T + Xi[:3, 3], distance_upper_bound=radius)
    return float(np.mean(np.isfinite(d)))


def feature_agreement(fW: np.ndarray, fO: np.ndarray, X_WO: np.ndarray, tol: float = 0.01) -> int:
    """Number of 3-D feature matches (point in W (F,3), point in O (F,3)) that pose X_WO maps within tol."""
    if len(fW) == 0:
        return 0
    Xi = X_inv(X_WO)
    return int(np.sum(np.linalg.norm(fW @ Xi[:3, :3].T + Xi[:3, 3] - fO, axis=1) < tol))


def score(frac: float, rmse: float, n_feat: int, w_feat: float, seen: float = 0.0, w_seen: float = 2.0) -> float:
    """Score of a re-localised pose: inlier fraction − 0.02 · RMSE/mm + w_feat · min(n_feat, 50)/50 − w_seen · the
    fraction of model points the frame sees through."""
    return frac - 0.02 * rmse / 0.001 + w_feat * min(n_feat, 50) / 50.0 - w_seen * seen


def place_score(P_W: np.ndarray, X_WO: np.ndarray, tree, Q_O: np.ndarray, view, radius: float = 0.01,
                w_seen: float = 2.0) -> float:
    """Coverage of the frame points P_W (N,3) by the model placed with X_WO (mean of max(0, 1 − d/radius), d the
    distance to the nearest model point) minus
    ``w_seen`` × the fraction of the model points Q_O (M,3) that the frame sees through (``view``: a ``FreeSpace``
    with the frame's own depth; its reading lies behind them). A partly seen box slid along its own face keeps
    every frame point covered, but its model then covers pixels where the frame sees the table or background."""
    Xi = X_inv(X_WO)
    d, _ = tree.query(P_W @ Xi[:3, :3].T + Xi[:3, 3], distance_upper_bound=radius)
    s = float(np.mean(np.clip(1.0 - d / radius, 0.0, 1.0)))  # soft coverage: peaks where the points lie on the model
    if view is not None and len(Q_O):
        s -= w_seen * float(np.mean(view.seen_through(Q_O @ X_WO[:3, :3].T + X_WO[:3, 3])))
    return s


def slide_search(P_W: np.ndarray, X_WO: np.ndarray, tree, Q_O: np.ndarray, view, half: float = 0.12,
                 step: float = 0.02, fine: float = 0.005) -> tuple[np.ndarray, float]:
    """The horizontal translation of X_WO (4,4) that maximises ``place_score`` on a grid of ±half (step ``step``),
    then ±step around the best (step ``fine``; 0: none), coverage counted within 0.6 × the grid step (≥ 1 cm): the
    slide along a face that point-to-plane ICP cannot see. Returns (pose, score of the last stage)."""
    best, s_best = X_WO, -np.inf
    for h, st in ((half, step), (step, fine)):
        if st <= 0:
            break
        rad = max(0.01, 0.6 * st)  # coverage radius of the grid's own resolution
        c = best.copy()
        s_best = place_score(P_W, c, tree, Q_O, view, radius=rad)
        g = np.arange(-h, h + 1e-9, st)
        for dx in g:
            for dy in g:
                Xc = c.copy()
                Xc[0, 3] += dx
                Xc[1, 3] += dy
                s = place_score(P_W, Xc, tree, Q_O, view, radius=rad)
                if s > s_best:
                    best, s_best = Xc, s
    return best, s_best
