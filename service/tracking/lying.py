"""A body of revolution lying on the table: its axis parallel to the table plane.

Geometry. A body of revolution whose profile ρ(h) (radius about the axis a at height h along it) has a straight
widest stretch — the cylindrical body of a bottle, a can, a mug's wall — rests on a flat table along that stretch:
its lowest generator line, {c + h a − ρ ẑ⊥}, touches the table over the stretch, so the generator and with it the
axis are parallel to the table plane (elevation of a in W: 0). Rolling without slip about the axis keeps that
contact line on the table, so the constraint holds while the body rolls as well as at rest.

Measured on the lab's bottle topples (development seeds 521, 531, 881; ground truth read by the diagnosis only;
docs/tracking-findings.md "Lying body levelled"): after the topple the tracked axis of the lying bottle points 1.3-5°
above or below the horizontal in every frame, the same in the tracking loop, in the keyframes after the bundle
adjustment and after the final pass: the keyframes after the landing were attached to the standing ones that way (a
gauge of the keyframes, not an error of single frames). The spin axis found on the final model (``spin.find_axis``) is
3-7° off the true one on these models, while the vertical of frame 0 is within 0.1°: the bottle stands on its base at
frame 0, and the base of a body of revolution is a disc perpendicular to its axis, so a body of revolution at rest on
the table at frame 0 with its axis within ``stand_deg`` of the vertical has the vertical of W at frame 0 as its axis;
X_WO(0) has identity rotation, so that is ẑ in O.

Correction (``level_lying``). With a = ẑ_O, the axis centre c fitted by circles to the model points in height
bins (``axis_centre``) and the profile's widest straight stretch (``straight_stretch``: bins whose median radius is
within ``tol`` of the widest, the longest run, at least ``min_len`` and ``min_frac`` of the model's height; an egg
has none), a frame lies on the table when the axis is within ``lie_deg`` of the horizontal in it and in its
±``half`` neighbours (a landing frame turns by 10-15° per frame: its neighbours are not lying) and the stretch's
lowest line is within ``margin`` of the table. Its pose is turned about the horizontal line through the axis point
nearest the model's centroid (the part of the body every frame's points register, so its position is kept) by the
angle that makes R_WO a horizontal: X_WO ← T(p) R_δ T(−p) X_WO. A frame whose correction exceeds ``max_deg`` is
left alone.
"""

from __future__ import annotations

import numpy as np

from service.tracking.spin import plane_basis
from service.transforms import horizontal_turn


def axis_centre(Q: np.ndarray, a: np.ndarray, bin_m: float = 0.005, min_pts: int = 30) -> np.ndarray | None:
    """(3,) a point of the axis line with direction a (3,) through the model points Q (M,3): the median over
    height bins (``bin_m`` along a, ≥ ``min_pts`` points) of the centres of algebraic least-squares circles fitted
    to the bin's points projected on the plane perpendicular to a; None without such a bin."""
    e1, e2 = plane_basis(a)
    P = np.c_[Q @ e1, Q @ e2]
    h = Q @ a
    centres = []
    for lo in np.arange(h.min(), h.max() + bin_m, bin_m):
        m = (h >= lo) & (h < lo + bin_m)
        if m.sum() < min_pts:
            continue
        A = np.c_[2.0 * P[m], np.ones(m.sum())]
        x, *_ = np.linalg.lstsq(A, (P[m] ** 2).sum(1), rcond=None)
        centres.append(x[:2])
    if not centres:
        return None
    c2 = np.median(np.array(centres), axis=0)
    return c2[0] * e1 + c2[1] * e2


def radius_profile(Q: np.ndarray, a: np.ndarray, c: np.ndarray, bin_m: float = 0.005, min_pts: int = 10
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(heights (B,), radii (B,), h (M,)) of the model points Q (M,3) about the axis line (direction a (3,), through c
    (3,)), all in m: for every height bin of ``bin_m`` along a with at least ``min_pts`` points, its centre height and
    the median distance of its points from the axis; h the points' heights along a from c."""
    d = Q - c
    h = d @ a
    r = np.linalg.norm(d - h[:, None] * a, axis=1)
    hs, rs = [], []
    for lo in np.arange(h.min(), h.max() + bin_m, bin_m):
        m = (h >= lo) & (h < lo + bin_m)
        if m.sum() >= min_pts:
            hs.append(lo + bin_m / 2)
            rs.append(float(np.median(r[m])))
    return np.array(hs), np.array(rs), h


def straight_stretch(Q: np.ndarray, a: np.ndarray, c: np.ndarray, *, bin_m: float = 0.005, tol: float = 0.002,
                     min_len: float = 0.05, min_frac: float = 0.4, min_pts: int = 10
                     ) -> tuple[bool, float, float]:
    """(found, length (m), radius (m)) of the widest straight stretch of the radius profile of the model points Q
    (M,3) about the axis (a, c): the median radius per height bin (``bin_m``, ≥ ``min_pts`` points), the bins
    within ``tol`` of the widest, their longest run (gaps of one bin closed); found when it is at least ``min_len``
    long and ``min_frac`` of the model's height (module docstring)."""
    hs, rs, h = radius_profile(Q, a, c, bin_m, min_pts)
    if len(hs) < 2:
        return False, 0.0, 0.0
    idx = np.nonzero(rs >= rs.max() - tol)[0]
    best, start = (idx[0], idx[0]), idx[0]
    for prev, k in zip(idx[:-1], idx[1:]):
        if hs[k] - hs[prev] > 2.01 * bin_m:
            start = k
        if hs[k] - hs[start] > hs[best[1]] - hs[best[0]]:
            best = (start, k)
    length = float(hs[best[1]] - hs[best[0]])
    radius = float(np.median(rs[best[0]:best[1] + 1]))
    return bool(length >= min_len and length >= min_frac * np.ptp(h)), length, radius


def lying_frames(X_WO: np.ndarray, a: np.ndarray, p_O: np.ndarray, radius: float, table_z: float, *,
                 lie_deg: float = 15.0, half: int = 3, margin: float = 0.015) -> np.ndarray:
    """(N,) bool: frames of the poses X_WO (N,4,4) in which the body (axis direction a (3,) in O, axis point p_O
    (3,), straight stretch of radius ``radius``) lies on the table at height table_z: the axis within ``lie_deg`` of
    the horizontal in the frame and its ±``half`` neighbours, the stretch's lowest line within ``margin`` of the
    table (module docstring)."""
    aW = np.einsum("nij,j->ni", X_WO[:, :3, :3], a)
    el = np.arcsin(np.clip(aW[:, 2], -1.0, 1.0))
    flat = np.abs(el) <= np.radians(lie_deg)
    n = len(X_WO)
    settled = np.array([flat[max(0, i - half):i + half + 1].all() for i in range(n)])
    pz = np.einsum("nj,j->n", X_WO[:, 2, :3], p_O) + X_WO[:, 2, 3]
    low = pz - radius * np.cos(el) <= table_z + margin
    return settled & low


def _lay_flat(a_W: np.ndarray) -> tuple[np.ndarray, float] | None:
    """(R (3,3), angle (rad)): the least rotation that makes the unit vector a_W (3,) horizontal
    (``transforms.horizontal_turn``, Rodrigues' formula); None when a_W is vertical or already horizontal."""
    turn = horizontal_turn(a_W)
    if turn is None or turn[1] < 1e-12:
        return None
    v, s, th = turn
    k = v / s
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(th) * K + (1.0 - np.cos(th)) * K @ K, th


def level_pose(X: np.ndarray, a: np.ndarray, p_O: np.ndarray) -> tuple[np.ndarray, float]:
    """(pose (4,4), angle (rad)): the pose X (4,4) turned about the horizontal line through its point p_O (3,) (in
    O) by the smallest rotation that makes its axis a (3,) horizontal in W."""
    lay = _lay_flat(X[:3, :3] @ a)
    if lay is None:
        return X.copy(), 0.0
    Rd, th = lay
    p = X[:3, :3] @ p_O + X[:3, 3]
    out = X.copy()
    out[:3, :3] = Rd @ X[:3, :3]
    out[:3, 3] = p + Rd @ (X[:3, 3] - p)
    return out, th


def lying_views_stretch(Q_lying: np.ndarray, a: np.ndarray, max_deg: float = 15.0, min_pts: int = 200
                        ) -> tuple[bool, float]:
    """(found, radius (m)) of the straight widest stretch of the lying views' own profile: the points Q_lying (M,3) in
    O of the keyframes in which the body lies on the table, about their own axis (``spin.profile_axis`` started from
    a (3,) through ``axis_centre``), which is not the merged model's: the lying views are attached to the standing
    ones with a common tilt of a few degrees (made in the fast fall), so about a they smear the profile, about their
    own axis they show the side of the body along its length. Not found with fewer than ``min_pts`` points, no axis
    centre, or their axis more than ``max_deg`` from a (the lying views do not agree on one body)."""
    from service.tracking.spin import profile_axis

    if len(Q_lying) < min_pts:
        return False, 0.0
    c0 = axis_centre(Q_lying, a)
    if c0 is None:
        return False, 0.0
    aL, cL, _ = profile_axis(Q_lying, a, c0)
    if abs(aL @ a) < np.cos(np.radians(max_deg)):
        return False, 0.0
    found, _, radius = straight_stretch(Q_lying, aL, cL)
    return found, radius


def lying_geometry(Q: np.ndarray, axis_O: np.ndarray, stand_deg: float = 15.0, Q_lying: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, float] | None:
    """(a, p_O, radius): the axis direction (the vertical of W at frame 0, ẑ in O), the axis point nearest the model's
    centroid and the radius of the profile's straight widest stretch of a body of revolution with model points Q (M,3)
    in O that stood on its base at frame 0 (found axis ``axis_O`` (3,) within ``stand_deg`` of ẑ); None when it did
    not stand so, no axis centre is found or the profile has no straight stretch (module docstring). ``Q_lying``
    (M',3) in O, optional: the points of the keyframes in which the body lies; when the merged profile has no
    straight stretch, the stretch (and its radius) of those views about their own axis (``lying_views_stretch``)."""
    a = np.array([0.0, 0.0, 1.0])  # the vertical of W at frame 0 in O (R_WO(0) = I)
    if abs(axis_O @ a) / np.linalg.norm(axis_O) < np.cos(np.radians(stand_deg)):
        return None
    c = axis_centre(Q, a)
    if c is None:
        return None
    found, _, radius = straight_stretch(Q, a, c)
    if not found and Q_lying is not None:
        found, radius = lying_views_stretch(Q_lying, a, stand_deg)
    if not found:
        return None
    return a, c + float(np.mean((Q - c) @ a)) * a, radius


def unseen_roll(X_WO: np.ndarray, Q: np.ndarray, table_z: float, axis_O: np.ndarray, *, stand_deg: float = 15.0,
                lie_deg: float = 15.0, margin: float = 0.015) -> float:
    """The largest roll (rad, ≥ 0) about its axis of a body of revolution lying on the table that the poses X_WO
    (N,4,4) do not show as a turn: over consecutive lying frames (``lying_frames``, geometry of ``lying_geometry``;
    model points Q (M,3) in O, found axis ``axis_O``, table height table_z) the roll without slip measured by the
    axis point's travel across the axis, Δφ = ΔP · u / r (u = a_W × ẑ / |a_W × ẑ|, r the straight stretch's radius:
    the contact line at rest, v_P = ω_a r u), minus the poses' own twist about the axis (``fall.twist_steps``),
    accumulated; the largest |sum| over the frames. 0 when the geometry is not found or no two consecutive frames
    lie."""
    from service.tracking.fall import twist_steps

    geo = lying_geometry(Q, axis_O, stand_deg)
    if geo is None or len(X_WO) < 2:
        return 0.0
    a, p_O, radius = geo
    lying = lying_frames(X_WO, a, p_O, radius, table_z, lie_deg=lie_deg, margin=margin)
    step = lying[1:] & lying[:-1]
    if not step.any():
        return 0.0
    aW = np.einsum("nij,j->ni", X_WO[:, :3, :3], a)
    u = np.cross(aW, np.array([0.0, 0.0, 1.0]))
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
    P = np.einsum("nij,j->ni", X_WO[:, :3, :3], p_O) + X_WO[:, :3, 3]
    dphi = np.einsum("ni,ni->n", P[1:] - P[:-1], u[1:]) / radius
    missed = np.where(step, dphi - twist_steps(X_WO, a)[1:], 0.0)
    return float(np.max(np.abs(np.cumsum(missed))))


def level_lying(X_WO: np.ndarray, Q: np.ndarray, table_z: float, axis_O: np.ndarray, *, stand_deg: float = 15.0,
                lie_deg: float = 15.0, margin: float = 0.015, max_deg: float = 10.0,
                Q_lying: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(poses (N,4,4), levelled (N,) bool): the poses X_WO (N,4,4) of a body of revolution with model points Q
    (M,3) in O, found axis ``axis_O`` (3,) and frame 0 at rest on the table at height table_z, with the frames in
    which it lies on the table turned so that its axis is parallel to the table (module docstring). Unchanged when
    the found axis is more than ``stand_deg`` from the vertical of frame 0 (the body did not stand on its base) or
    the profile has no straight stretch (``Q_lying``: the lying keyframes' points in O, whose own profile is
    searched when the merged one has none; ``lying_geometry``)."""
    n = len(X_WO)
    none = np.zeros(n, bool)
    geo = lying_geometry(Q, axis_O, stand_deg, Q_lying)
    if geo is None:
        return X_WO.copy(), none
    a, p_O, radius = geo
    lying = lying_frames(X_WO, a, p_O, radius, table_z, lie_deg=lie_deg, margin=margin)
    out = X_WO.copy()
    done = none.copy()
    for i in np.nonzero(lying)[0]:
        Xi, th = level_pose(X_WO[i], a, p_O)
        if abs(th) <= np.radians(max_deg):
            out[i], done[i] = Xi, True
    return out, done


# ---- a fall the loop loses: the landing carried by the turn about the base rim (``lost_land``) ----------------------
#
# A body of revolution that stood on its base and topples turns about the point of its base rim that stays on the
# table (the pivot) until its side meets the table: for a body whose widest straight stretch starts at the base (a
# bottle, a can), the axis is then horizontal at the base radius r above the table and the base centre stands above
# the pivot. From a pose X_a of the fall (axis a_W tilted by θ toward the horizontal direction f), that is the turn
# about the horizontal line through the pivot (the lowest point of the base rim, r (cos θ f − sin θ ẑ) from the base
# centre, put on the table) by the least rotation that makes a_W horizontal (90° − θ). Where the loop loses the fall,
# the frames after the landing show the lower part of the body that the model does not hold (or holds misplaced), so
# a re-acquisition can lay it along the modelled upper part (slid 60-110 mm along the axis or turned 80-110° about a
# horizontal axis; docs/tracking-findings.md "Bottle topples whose track is lost in the fall"): the turn's pose says
# where the body is along its axis and how its axis lies, not its spin about the axis (left to the spin closure) and
# not a roll or slide after the landing.

def base_rim(Q: np.ndarray, a: np.ndarray, base_h: float, bin_m: float = 0.005, min_pts: int = 30
             ) -> tuple[np.ndarray, float] | None:
    """(b_O (3,), radius (m)): the base centre of a body of revolution with model points Q (M,3) in O and axis
    direction a (3,) (the vertical of frame 0), whose base lies at height ``base_h`` along a (the table at frame 0),
    and its widest radius (the largest median radius over height bins of ``bin_m`` with ≥ ``min_pts`` points about
    the axis line through ``axis_centre``); None without an axis centre."""
    c = axis_centre(Q, a, bin_m, min_pts)
    if c is None:
        return None
    _, rs, _ = radius_profile(Q, a, c, bin_m, min_pts)
    if not len(rs):
        return None
    return c + (base_h - float(c @ a)) * a, float(rs.max())


def rim_landing(X: np.ndarray, a: np.ndarray, b_O: np.ndarray, radius: float, table_z: float
                ) -> np.ndarray | None:
    """(4,4) X_WO: the pose X (4,4) of a falling body of revolution (axis a (3,) in O, base centre b_O (3,) in O,
    base radius ``radius`` m), moved vertically until its base rim's pivot is on the table at height table_z, turned
    about the horizontal line through the pivot until its axis is horizontal (comment above); None when the axis is vertical in X (no tipping
    direction) or already horizontal."""
    w = X[:3, :3] @ a
    z = np.array([0.0, 0.0, 1.0])
    down = (w @ z) * w - z  # the steepest descent within the base disc
    if np.linalg.norm(down) < 1e-9:
        return None
    lay = _lay_flat(w)
    if lay is None:
        return None
    Rd, _ = lay
    p = X[:3, :3] @ b_O + X[:3, 3] + radius * down / np.linalg.norm(down)
    t = X[:3, 3] + np.array([0.0, 0.0, table_z - p[2]])  # the body moved vertically until its pivot is on the table
    p[2] = table_z
    out = X.copy()
    out[:3, :3] = Rd @ X[:3, :3]
    out[:3, 3] = p + Rd @ (t - p)
    return out


def axial_gap(X: np.ndarray, X_ref: np.ndarray, a: np.ndarray, b_O: np.ndarray) -> tuple[float, float]:
    """(angle (deg), offset (m)) of the pose X (4,4) from X_ref (4,4) for a body of revolution (axis a (3,) in O,
    base centre b_O (3,) in O): the angle between their axes in W (a turn about a horizontal axis for a lying body;
    the spin about the axis is not counted) and the base centre's offset along X_ref's axis, |·|."""
    wa, wr = X[:3, :3] @ a, X_ref[:3, :3] @ a
    ang = float(np.degrees(np.arccos(np.clip(wa @ wr / (np.linalg.norm(wa) * np.linalg.norm(wr)), -1.0, 1.0))))
    d = (X[:3, :3] @ b_O + X[:3, 3]) - (X_ref[:3, :3] @ b_O + X_ref[:3, 3])
    return ang, abs(float(d @ wr) / float(np.linalg.norm(wr)))


def topple_time(theta: float, omega: float, radius: float, height: float, g: float = 9.81, steps: int = 400
                ) -> float:
    """Time (s) a body of revolution toppling about its base rim takes from the tilt ``theta`` (rad, of its axis from
    the vertical) at the tilt rate ``omega`` (rad/s) to lie (tilt π/2), taken as a uniform solid cylinder of base
    radius ``radius`` and height ``height`` (m): its centre of mass at d = √(r² + (H/2)²) from the pivot, at the angle
    β = atan(2r/H) from the axis, moment of inertia about the pivot line I/m = r²/4 + H²/12 + d². Energy:
    ω(θ)² = ω₀² + (2 g d / (I/m)) (cos(θ₀ − β) − cos(θ − β)); t = ∫ dθ / ω (midpoint rule, ``steps``). inf when the
    body does not reach π/2 (it falls back). A fall only speeds up past the balance tilt β, so a rate measured a few
    frames before (lower than the rate at θ) gives a longer time: a bound on when it has landed."""
    d = float(np.hypot(radius, 0.5 * height))
    beta = float(np.arctan2(radius, 0.5 * height))
    k = 2.0 * g * d / (0.25 * radius**2 + height**2 / 12.0 + d**2)
    if theta >= 0.5 * np.pi:
        return 0.0
    th = np.linspace(theta, 0.5 * np.pi, steps + 1)
    mid = 0.5 * (th[1:] + th[:-1])
    w2 = omega**2 + k * (np.cos(theta - beta) - np.cos(mid - beta))
    if np.any(w2 <= 0):
        return float(np.inf)
    return float(np.sum(np.diff(th) / np.sqrt(w2)))


# ---- a lying body's position along its axis from the ends of its mask (``lie_axis_ends``) -------------------------
#
# A body of revolution lying on the table registers to a model that cannot see a slide along its own axis: the side
# of a cylinder fits the frame's points wherever it is along the axis, and the lying views attached in a fast fall
# keep the slide the loop made there (development bottle topples 1697, 1788, 1789: 27-60 mm along the axis in every
# lying frame, docs/tracking-findings.md "A lying bottle's position along its axis"). Its ends are where it is: the
# base end lies where the table was at frame 0 (the body stood on its base: ẑ_O = a, the base plane at the table's
# height in O), the cap end where the standing frames saw the top (the extreme of their mask points along a). A lying
# frame whose mask shows an end (``resettle.end_seen``: nothing nearer the camera beyond it) places the body along a.
# The extreme of a mask along a falls short of the true end by the edge pixels the depth filter drops and the rounded
# rim (``short``, each end); with both ends seen the middle is compared and the shortfalls cancel.

def lying_runs(lying: np.ndarray, min_len: int = 5, gap: int = 3) -> list[tuple[int, int]]:
    """[(start, stop), ...] (stop exclusive): the runs of True in the (N,) bool ``lying`` with gaps of at most ``gap``
    frames closed, each at least ``min_len`` frames long (the stretches a body lies on the table between falls)."""
    idx = np.nonzero(np.asarray(lying, bool))[0]
    if not len(idx):
        return []
    runs, s = [], idx[0]
    for p, q in zip(idx[:-1], idx[1:]):
        if q - p > gap + 1:
            runs.append((int(s), int(p) + 1))
            s = q
    runs.append((int(s), int(idx[-1]) + 1))
    return [(a, b) for a, b in runs if b - a >= min_len]


def axis_end_offsets(base: float | None, top: float | None, post: np.ndarray, short: float,
                     len_tol: float = 0.008) -> np.ndarray:
    """(M,) the offset (m) along a lying body's axis a of each lying frame from the model's ends, NaN where the frame
    does not count: ``base`` and ``top`` the ends along a in O (the base plane from the table at frame 0, the top from
    the standing frames; None when unknown), ``post`` (M,2) per lying frame the (lo, hi) extent of its mask along a in
    O (``resettle.axis_extent``), NaN in a column whose end is not seen (``resettle.end_seen``). With both ends seen
    (and both known): the middle minus the model's middle, when the length is within ``len_tol`` of the model's
    length less 2 ``short`` (else an end is cut that the end test passed, and the frame does not count); with one
    seen, that end minus the model's, less the mask's shortfall ``short`` toward the inside. A frame whose pose sits
    δ along a from the body's place has its points carried into O at −δ: the offset is −δ, and
    ``resettle.moved_along(X, a, offset)`` puts it back."""
    post = np.asarray(post, float).reshape(-1, 2)
    c = np.full(len(post), np.nan)
    if len(post) == 0 or (base is None and top is None):
        return c
    lo_ok = np.isfinite(post[:, 0]) & (base is not None)
    hi_ok = np.isfinite(post[:, 1]) & (top is not None)
    if base is not None and top is not None:
        both = lo_ok & hi_ok
        L = post[:, 1] - post[:, 0]
        good = both & (np.abs(L - (top - base - 2.0 * short)) <= len_tol)
        c[good] = post[good].sum(1) / 2.0 - (base + top) / 2.0
        lo_ok &= ~both
        hi_ok &= ~both
    if base is not None:
        c[lo_ok] = post[lo_ok, 0] - base - short
    if top is not None:
        c[hi_ok] = post[hi_ok, 1] - top + short
    return c


def axis_end_shift(c: np.ndarray, t: np.ndarray, *, window: float = 15.0, spread_tol: float = 0.004, min_n: int = 5,
                   min_frac: float = 0.5, min_shift: float = 0.008) -> np.ndarray | None:
    """(M,) the shift (m) along a lying body's axis of each measured frame of one lying stretch (frame numbers t (M,)),
    from its offsets c (M,) (``axis_end_offsets``, NaN: not counted): the running median of the counted offsets within
    ± ``window`` frames (the loop's slide along the axis grows while the body is pushed and rolls: development 1788
    −65 → −56 mm over 200 frames), at the frames without one the nearest counted value. None (no shift) when fewer
    than ``min_n`` and ``min_frac`` of the frames count, the counted offsets spread about their running median more
    than ``spread_tol`` (interquartile range: the ends disagree), or the stretch's median offset is under
    ``min_shift``."""
    c, t = np.asarray(c, float), np.asarray(t, float)
    ok = np.isfinite(c)
    if ok.sum() < max(min_n, min_frac * len(c)):
        return None
    tc, cc = t[ok], c[ok]
    run = np.array([np.median(cc[np.abs(tc - x) <= window]) for x in tc])
    q1, q3 = np.quantile(cc - run, [0.25, 0.75])
    if q3 - q1 > spread_tol or abs(float(np.median(cc))) < min_shift:
        return None
    return np.interp(t, tc, run)
