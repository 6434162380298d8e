"""The settled object after a topple's landing, joined to the pre-fall model by the fall's physics.

A topple ends with 1–3 frames turning 14–16° each while the occluder may hide most of the object; the tracking
loop can lose the object there and carry on at a consistent wrong pose (development milk_carton topple 820:
107 mm / 9° off from the landing to the end). A re-localisation of the settled object against the pre-fall model cannot
fix it: the pre-fall model holds mostly the object's upper part, the settled view mostly surface never seen before (the
former ``settle`` option, docs/tracking-findings.md), and the lab's six-tile print gives no ORB match between the two
views either (no side is seen both before and after the fall in those sessions). What they do share is the motion
between them: a topple is a rotation about the bottom edge on the table in the direction it started to tip, ending when
the side face that led lies on the table.

Mechanism (in the tracking loop, ``tracker._resettle_check``):
1. Detection (``find_fall``): frame i is tracked ``delay`` frames after the last fast step of the loop (a step
   turning more than ``fast_deg`` per frame, or a loss over which the pose turned more than half that per frame),
   with no fast step since. The fall started at g0 (walking back while the steps turn more than ``fall_deg`` per
   frame), and the tipping at r ≤ g0 (walking back while steps turn more than ``tip_deg`` per frame): the turn
   tracked from r to the frame before the fast step must be at least ``min_tip_deg`` about a nearly horizontal
   axis h (|h_z| ≤ 0.35).
2. Join (``landing_pose``), from the pre-fall model Q (keyframes before g0) at the rest pose X_r: the side face
   that leads (``face_plane``: the model's points with normals within 30° of the tipping direction f = h × z, a
   plane fitted to them; 80 % of them within 4 mm of it, else no face — an egg, a bottle's side) is turned about
   the line where its plane meets the table, by the angle that lays its normal on −z (h only picks the face). It
   then lies on the table; the turn's direction comes from the face, not from the lagging tracked turn.
   Horizontal position corrected by the faces both views show (``face_offsets``: per dominant horizontal
   direction of the model's normals, the plane offset of the model's points and of the frame's points with
   normals within 20° of it; corrections above ``max_shift`` are left out; the yaw is not corrected) and by the
   reach of the frame's points along f (``reach_along``: the model's top end must reach at least as far).
   With ``resettle_box_face`` (on) and no leading face in the model (a box that tips away from the camera shows
   it to no pre-fall view), the leading face of a box is taken from its seen flat sides (``box_face``: at right
   angles, squared to the base, the side direction nearest f, at the model's extent along it) — only when the body
   rests on the table at frame i (``box_landing_pose``, ``on_table``: the lowest point of the tracker's model under
   the tracked pose at most ``resettle_box_rest`` above the table plane): a landing is a body coming to rest on the
   table, and a box held in the air by a gripper, turned during a carry, is not landing. With ``resettle_box_drop``
   (off) such a join is moved by the drop the face on top of the landed box shows (``top_face_drop``: a face placed
   at the model's extent turns the box about an edge short of the true one, leaving it short and low).
3. When the object has a leading face, the join differs from the tracked pose by more than ``min_deg`` /
   ``min_dist`` and puts no more of the pre-fall model where frame i sees the table or background than the tracked
   pose does (the frame's own depth as free space), frame i takes it, the keyframes from g0 on are dropped and
   frame i becomes a keyframe with all its points (the settled object's model of its own, joined to the pre-fall
   one by the pose); the loop continues from it and the fall's frames are registered backwards from it after the
   loop (``tracker._settle_backward``).
4. After the loop (``tracker._resettle_refine``, ``resettle_refine_frames``): the join is moved forward along f
   until the object's base (``base_points``: the table plane under the rest pose, within the model's footprint)
   no longer lies where the settled frames see the table or background (``base_shift``); the lab's cartons land
   6–15 mm beyond the pure turn about the edge, and after the topple the base faces −f, behind the object.
5. (Removed options: the leading face squared to the base, a join near a track that does not rest on the table
   adopted; docs/tracking-findings.md.)
6. After the gauge (``tracker._resettle_flush``, ``resettle_flush_deg``): in the settled stretch of every landing
   checked (adopted or not) the face of the pre-fall model lying on the table (``landed_face``, its normal squared to
   the base the object stood on) is laid flush with the table (``flush_pose``: an object at rest on a face has it on
   the table; two tilts and the height), or, when that face was never seen, the base is made vertical
   (``side_pose``); the stretch's keyframes move with their frames, the model is rebuilt and every frame is
   registered again in the motions that keep it resting (``planar_register``: a turn about the vertical, a
   horizontal shift). With ``resettle_box_flush`` (off) a box lying on a side it never showed has that side, found
   from its seen sides (``box_rest_face``), laid flat (``down_pose``: two tilts) instead of only its base made vertical.
7. The frames at rest before the settled frame (``resettle_flush_rest_tol``): the settled frame i comes
   ``delay`` frames after the last fast step, so the frames between the landing and i, at rest already, kept
   their own (fall or landing) poses. Walking back from i, every frame whose object points lie on frame i's
   (``still_fit``) and whose ORB keypoints lie within a few millimetres of their partners in frame i (the object
   has not moved, seen by the frames themselves, no pose involved) takes frame i's final pose moved by the small
   rigid motion its keypoints show (the last slide or rocking of a landed box; ``tracker._rest_before``).
8. After the flush (``tracker._resettle_axis``, ``resettle_box_axis``): a box's settled stretch moved along its tip
   axis h so that the middle of its two ends along h (``axis_extent``: the extreme of the mask's depth points, both
   ends seen, ``end_seen``) lies where the frames before the fall saw it (``axis_shift``, ``moved_along``): the
   landing's sideways slide, which no surface seen before and after the landing fixes. With ``resettle_box_slide``
   (off) the same along the box's up axis, which the topple lays along the tipping direction f: the middle of the
   settled ends along it against the standing box's, from the table under its base (``table_end``) to its top (the
   landing's slide beyond the pure turn; the base end is often hidden where the box stood, then nothing is moved).
What is left: the join is 0.5–2° off (a yaw the table does not fix) and up to 9 mm sideways; the base test is a lower bound of the slide
along f (a join that overshoots is not pulled back), and it needs the frames to see the table behind the base.
References: rigid-body toppling about a contact edge (e.g. Lynch & Mason 1999, "Dynamic nonprehensile
manipulation"); plane-based registration (Pathak et al. 2010, "Fast registration based on noisy planes").
Every fall checked is recorded as a ``Landing``. The table and the frame's free space test a pose
(``pose_consistent``): a pose whose model Q_O (M,3) lies through the table (heights z = (X_WO Q_O)_z below the table
height h − margin) or covers pixels where the frame sees the table or background behind it is inconsistent (a box
slid along its own face keeps every frame point on the model, but its model then lies where the frame sees the table).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from service.tracking.geometry import backproject
from service.transforms import X_inv, horizontal_turn, make_X, pose_distance, so3_exp, so3_log


def _step(X: np.ndarray, k: int, j: int) -> float:
    return pose_distance(X[k], X[j])[1] / max(1, j - k)


def find_fall(X: np.ndarray, tracked: np.ndarray, i: int, fast_deg: float, fall_deg: float, tip_deg: float,
              min_tip_deg: float, delay: int, after: int = 0) -> tuple[int, int, int, np.ndarray] | None:
    """(r, g0, f, h) when frame i (tracked) comes ``delay`` or more frames after the last fast step f of the track
    and within 2 × delay of it (the first such tracked frame): r the start of the tipping, g0 the start of the fall,
    h (3,) the horizontal unit axis of the turn tracked from r to the last frame before f (in W). None when there is
    no such step after ``after`` or the turn is not a tip.
    X (N,4,4) poses so far, tracked (N,)."""
    idx = [j for j in range(max(0, after), i + 1) if tracked[j]]
    if len(idx) < 3 or idx[-1] != i:
        return None
    fast = None
    for k, j in zip(idx[:-1], idx[1:]):
        if i - j >= 2 * delay:
            continue  # a fast step that old is not looked at (and a later one would be the last)
        da = _step(X, k, j)
        if da > fast_deg or (j - k > 1 and da > 0.5 * fast_deg):
            fast = j
    if fast is None or not (delay <= i - fast < 2 * delay):
        return None
    # only the first tracked frame at least `delay` after the fast step
    if any(tracked[j] for j in range(fast + delay, i)):
        return None
    pre = [j for j in idx if j < fast]
    if len(pre) < 3:
        return None
    # fall start g0: walk back while the steps turn faster than fall_deg per frame
    p = len(pre) - 1
    while p > 0 and _step(X, pre[p - 1], pre[p]) > fall_deg:
        p -= 1
    g0 = pre[p]
    q = p
    while q > 0 and _step(X, pre[q - 1], pre[q]) > tip_deg:
        q -= 1
    r = pre[q]
    w = so3_log(X[pre[-1]][:3, :3] @ X[r][:3, :3].T)  # the whole turn tracked before the fast step
    ang = np.degrees(np.linalg.norm(w))
    if ang < min_tip_deg:
        return None
    h = w / np.linalg.norm(w)
    if abs(h[2]) > 0.35:
        return None  # not a tip about an edge on the table
    h = np.array([h[0], h[1], 0.0])
    return r, g0, fast, h / np.linalg.norm(h)


def dominant_normal(N: np.ndarray, d: np.ndarray, cos_min: float, min_frac: float) -> np.ndarray | None:
    """Mean (unit) of the normals N (M,3) within acos(cos_min) of the unit direction d, when at least ``min_frac``
    of them are; else None."""
    sel = N @ d > cos_min
    if sel.sum() < max(10, min_frac * len(N)):
        return None
    n = N[sel].mean(0)
    return n / np.linalg.norm(n)


def face_plane(P: np.ndarray, N: np.ndarray, d: np.ndarray, cos_min: float, min_frac: float,
               flat_tol: float = 0.004, flat_frac: float = 0.8) -> tuple[np.ndarray, float] | None:
    """The plane (unit normal n oriented like d, offset n·p) of the points P (M,3) whose normals N (M,3) lie within
    acos(cos_min) of the unit direction d (at least ``min_frac`` of them and 10): normal from the smallest principal
    axis of those within 1 cm of their median plane, offset the median. None when too few, or when fewer than
    ``flat_frac`` of the points with normals within 45° of n lie within ``flat_tol`` of that plane (a curved
    surface such as the lab's egg, 6.5 × 9 cm: its 45° cap is 9 mm deep; no face)."""
    n0 = dominant_normal(N, d, cos_min, min_frac)
    if n0 is None:
        return None
    sel = N @ d > cos_min
    F = P[sel]
    F = F[np.abs((F - np.median(F, 0)) @ n0) < 0.01]
    if len(F) < 10:
        return None
    w, V = np.linalg.eigh(np.cov((F - F.mean(0)).T))
    n = V[:, 0] * np.sign(V[:, 0] @ n0)
    if n @ n0 < np.cos(np.radians(15.0)):
        n = n0  # a thin strip: its principal axes do not give the face's normal
    d = float(np.median(F @ n))
    wide = N @ n > np.cos(np.radians(45.0))  # a box face has no neighbour within 45°; a curved cap keeps going
    if np.mean(np.abs(P[wide] @ n - d) < flat_tol) < flat_frac:
        return None  # curved (an egg, a bottle's side): no flat face
    return n, d


def landing_pose(X_r: np.ndarray, h: np.ndarray, Q_O: np.ndarray, N_O: np.ndarray, table_height: float,
                 face_cos: float = np.cos(np.radians(30.0)), box_base_O: np.ndarray | None = None
                 ) -> tuple[np.ndarray, bool]:
    """Pose (4,4) of the object after tipping about the horizontal unit axis h (3,) from rest pose X_r until its
    leading face lies on the table (see module docstring, step 2). Q_O, N_O (M,3): the pre-fall model.
    With the leading face in the model (``face_plane``), the turn is about the horizontal line where its plane meets
    the table, by the angle that lays its normal n_f on −z (h only picks the face); without it, 90° about h through
    the model's extent along the tipping direction on the table, then lowered onto the table.
    With ``box_base_O`` (3,: the unit normal, in O, of the base the object stood on) and no leading face in the model
    (a box that tips away from the camera: the face that leads was never seen), the leading face of a box
    (``box_face``: its seen flat sides at right angles, the one nearest f) takes its place, at the model's extent
    along its normal.
    Returns (pose, whether the leading face was found or, with ``box_base_O``, inferred from a box's sides)."""
    R_r, t_r = X_r[:3, :3], X_r[:3, 3]
    P = Q_O @ R_r.T + t_r
    Nw = N_O @ R_r.T
    z = np.array([0.0, 0.0, 1.0])
    f = np.cross(h, z)  # the top moves along f for a positive turn about h
    c = P.mean(0)
    plane = face_plane(P, Nw, f, face_cos, 0.03)
    if plane is None and box_base_O is not None:
        plane = box_face(P, Nw, f, R_r @ box_base_O)
    if plane is not None and np.hypot(*plane[0][:2]) > 0.7:
        n_f, d_f = plane
        u = np.array([n_f[0], n_f[1], 0.0])
        u /= np.linalg.norm(u)
        h_f = np.cross(z, u)  # horizontal, normal to n_f: the edge the object turns about
        base = np.array([c[0], c[1], table_height])
        pivot = base + (d_f - n_f @ base) / (n_f @ u) * u
        ang = np.arctan2(np.cross(n_f, -z) @ h_f, n_f @ -z)
        R_turn = so3_exp(h_f * ang)
        R = R_turn @ R_r
        return make_X(R, pivot + R_turn @ (t_r - pivot)), True
    ext = float(np.max(P @ f))
    pivot = np.array([0.0, 0.0, table_height])
    pivot[:2] = (ext * f)[:2] + (c - (c @ f) * f)[:2]
    R_turn = so3_exp(h * np.pi / 2)
    R = R_turn @ R_r
    X = make_X(R, pivot + R_turn @ (t_r - pivot))
    X[2, 3] += table_height - float(np.min(Q_O @ R[2] + X[2, 3]))
    return X, False


def box_face(P: np.ndarray, N: np.ndarray, f: np.ndarray, b: np.ndarray, side_cos: float = 0.3,
             square_deg: float = 10.0, max_faces: int = 3) -> tuple[np.ndarray, float] | None:
    """The leading face of a box from its other sides, when the face itself was never seen: the plane (unit normal n,
    offset n·p) whose normal is the side direction nearest the tipping direction f (3,), among the directions at right
    angles of the seen flat sides, squared to the base, and whose offset is the extent of the points P (M,3) along n
    (the face lies at least that far; ``reach_along`` and the refinement move it on). P, N (M,3) the model and its
    normals, b (3,) the unit normal of the base it stood on, all in the same frame. The sides: the points with
    normals within acos(``side_cos``) of perpendicular to b; up to ``max_faces`` flat sides are found in turn
    (``face_plane`` about the most common side normal, then the normals more than 30° from it; its 4 mm flatness test
    refuses an egg's or a bottle's side); the first, squared to b, gives the box's side directions ±s and ±(b × s).
    None when no flat side is seen or when a seen flat side lies more than ``square_deg`` from those directions (a
    prism with other angles, not a box)."""
    b = b / np.linalg.norm(b)
    side = np.abs(N @ b) < side_cos
    dirs: list[np.ndarray] = []
    left = side.copy()
    for _ in range(max_faces):
        if left.sum() < 30:
            break
        S = N[left]
        sub = S[:: max(1, len(S) // 300)]
        d = sub[int(np.argmax([(S @ s > np.cos(np.radians(20.0))).sum() for s in sub]))]
        plane = face_plane(P, N, d, np.cos(np.radians(30.0)), 0.03)
        left &= N @ d < np.cos(np.radians(30.0))
        if plane is not None:
            dirs.append(plane[0])
    if not dirs:
        return None
    s = dirs[0] - (dirs[0] @ b) * b
    s /= np.linalg.norm(s)
    axes = np.array([s, -s, np.cross(b, s), -np.cross(b, s)])
    for n in dirs[1:]:
        m = n - (n @ b) * b
        m /= np.linalg.norm(m)
        if np.max(axes @ m) < np.cos(np.radians(square_deg)):
            return None  # not at right angles: not a box
    n = axes[int(np.argmax(axes @ f))]
    return n, float(np.max(P @ n))


def on_table(X_WO: np.ndarray, Q_O: np.ndarray, table_height: float, tol: float) -> bool:
    """Whether a body at pose X_WO (4,4) rests on the table: the lowest of its model points Q_O (M,3, in O) lies at
    most ``tol`` (m) above the table plane z = ``table_height`` (W). Below the plane counts as resting (a wrong pose
    of a body on the table, not a body held above it)."""
    return bool(np.min(heights(X_WO, Q_O)) <= table_height + tol)


def box_landing_pose(X_r: np.ndarray, h: np.ndarray, Q_O: np.ndarray, N_O: np.ndarray, table_height: float,
                     box_base_O: np.ndarray, X_i: np.ndarray, Q_i: np.ndarray | Callable[[], np.ndarray],
                     rest: float, top: tuple[np.ndarray, np.ndarray, float] | None = None) -> tuple[np.ndarray, bool]:
    """``landing_pose`` of the pre-fall model Q_O, N_O (M,3) from rest pose X_r (4,4) about h (3,); when that model
    has no leading face, the leading face of a box (``box_base_O``, see ``landing_pose``) is taken from its sides
    only if the body rests on the table at the settled frame (``on_table``: the model Q_i (K,3, in O) under the
    tracked pose X_i (4,4) within ``rest`` (m) of the table plane). A box held in the air (carried by a gripper and
    turned) is not landing: its join is left without a face, as without ``box_base_O``. ``Q_i`` may be a callable
    returning that model, called only when the pre-fall model has no leading face. With ``top`` = (P_W, N_W (N,3):
    the settled frame's points and normals in W, max_shift in m), a join on a face taken from the box's sides is
    moved by the drop the face on top shows (``top_face_drop``). Returns (pose, face)."""
    X, face = landing_pose(X_r, h, Q_O, N_O, table_height)
    if face or not on_table(X_i, Q_i() if callable(Q_i) else Q_i, table_height, rest):
        return X, face
    X, face = landing_pose(X_r, h, Q_O, N_O, table_height, box_base_O=box_base_O)
    if face and top is not None:
        X = top_face_drop(X, X_r, Q_O, N_O, top[0], top[1], table_height, top[2])
    return X, face


def top_face_drop(X: np.ndarray, X_r: np.ndarray, Q_O: np.ndarray, N_O: np.ndarray, P_W: np.ndarray,
                  N_W: np.ndarray, table_height: float, max_shift: float, cos_min: float = np.cos(np.radians(20.0)),
                  min_pts: int = 30) -> np.ndarray:
    """A box's join on a leading face placed at the model's extent (``box_face``) corrected by the face on top of
    the landed box. That face lies at least that far (the model may lack the strip of the box next to a face it never
    saw), so the join turns about an edge δ short of the true one and leaves the box δ short along the face's
    horizontal normal u and δ low: a turn about a line through p by R moves x to p + R(x − p), and moving p by δu
    moves the result by δ(u − R u) = δ(u + z), since R lays u on −z. The box lies on that face, so the height of the
    face on top above the table is the box's thickness across it, measured by the settled frame: δ is the median
    height of the frame's points P_W (N,3, in W) whose normals N_W lie within acos(``cos_min``) of +z (1 cm or more
    above the table) minus that of the pre-fall model's (Q_O, N_O (M,3), in O) under the join X (4,4), with at least
    ``min_pts`` of each. u is the horizontal direction of the join's turn from the rest pose X_r (4,4)
    (``tip_direction``). X moved by δ(u + z) when 0 < δ ≤ ``max_shift`` (m); else X unchanged (the face seen on top
    in the pre-fall model only when the box tips away from the camera: the trailing face, the one it showed)."""
    Nm = N_O @ X[:3, :3].T
    zm = Q_O[Nm[:, 2] > cos_min] @ X[2, :3] + X[2, 3]
    zf = P_W[(N_W[:, 2] > cos_min) & (P_W[:, 2] > table_height + 0.01), 2]
    tip = tip_direction(X_r, X)
    if len(zm) < min_pts or len(zf) < min_pts or tip is None:
        return X
    d = float(np.median(zf) - np.median(zm))
    if not 0.0 < d <= max_shift:
        return X
    X = X.copy()
    X[:3, 3] += d * (tip[0] + np.array([0.0, 0.0, 1.0]))
    return X


def reach_along(X: np.ndarray, Q_O: np.ndarray, P_W: np.ndarray, f: np.ndarray, max_shift: float,
                q: float = 99.0) -> np.ndarray:
    """Pose X (4,4) moved along the horizontal unit direction f (3,) so that the model Q_O (M,3) reaches at least as
    far along f as the frame's points P_W (N,3) (``q``-th percentiles): every observed point belongs to the object,
    so its end lies at least that far (the tipped object's top end leads along f); the frame may see less (an
    occluder), so the model is never pulled back. Shifts above ``max_shift`` are left out."""
    s = float(np.percentile(P_W @ f, q) - np.percentile((Q_O @ X[:3, :3].T + X[:3, 3]) @ f, q))
    if 0.0 < s <= max_shift:
        X = X.copy()
        X[:3, 3] += s * f
    return X


def face_offsets(X: np.ndarray, Q_O: np.ndarray, N_O: np.ndarray, P_W: np.ndarray, N_W: np.ndarray,
                 cos_face: float = np.cos(np.radians(20.0)), min_pts: int = 30, max_shift: float = 0.03
                 ) -> np.ndarray:
    """Pose X (4,4) corrected horizontally by the faces the model (Q_O, N_O (M,3)) and the frame (P_W, N_W (N,3))
    both show: the dominant horizontal normal directions of the model placed with X (within 20°: a face) are matched
    to the frame's points with normals within 20°; per face the difference of plane offsets (median) along its
    normal; the horizontal translation solves those in least squares. Corrections above ``max_shift`` are left out.
    The turn about the vertical is not corrected (a yaw from the matched normals made two of three development joins
    worse: docs/tracking-findings.md, "Worst frames of l_block 702 and milk_carton topple 710")."""
    R, t = X[:3, :3], X[:3, 3]
    Qw = Q_O @ R.T + t
    Nw = N_O @ R.T
    faces = []
    rest = np.ones(len(Nw), bool)
    for _ in range(4):  # up to four horizontal face directions of the model
        cand = rest & (np.abs(Nw[:, 2]) < 0.5)
        if cand.sum() < min_pts:
            break
        # the densest direction among the candidates
        sub = np.nonzero(cand)[0][:: max(1, cand.sum() // 400)]
        cnt = [(np.sum(Nw[cand] @ Nw[k] > cos_face), k) for k in sub]
        c, k = max(cnt)
        if c < min_pts:
            break
        n = Nw[cand & (Nw @ Nw[k] > cos_face)].mean(0)
        n[2] = 0.0
        n /= np.linalg.norm(n)
        sel = Nw @ n > cos_face
        rest &= ~sel
        selP = N_W @ n > cos_face
        if sel.sum() >= min_pts and selP.sum() >= min_pts:
            faces.append((n, Qw[sel], P_W[selP]))
    if not faces:
        return X
    X2 = X.copy()
    A, b = [], []
    for n, Qf, Pf in faces:
        d_m = float(np.median(Qf @ n))
        d_f = float(np.median(Pf @ n))
        if abs(d_f - d_m) <= max_shift:
            A.append(n[:2])
            b.append(d_f - d_m)
    if A:
        sol, *_ = np.linalg.lstsq(np.array(A), np.array(b), rcond=None)
        if np.linalg.norm(sol) <= max_shift:
            X2[:2, 3] += sol
    return X2


def base_points(Q_O: np.ndarray, X_0: np.ndarray, table_height: float, step: float = 0.003,
                inset: float = 0.005) -> np.ndarray:
    """(B,3) points of the object's base in O: the table plane under the rest pose X_0 (4,4) within the convex hull
    of the model Q_O (M,3) seen from above at rest, ``inset`` inside its boundary (a prism's base is its
    cross-section; the pre-fall views see the sides, never the base), on a ``step`` grid."""
    from scipy.spatial import ConvexHull

    P = Q_O @ X_0[:3, :3].T + X_0[:3, 3]
    xy = P[:, :2]
    lo, hi = xy.min(0), xy.max(0)
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0], step), np.arange(lo[1], hi[1], step))
    G = np.stack([gx.ravel(), gy.ravel()], 1)
    try:
        eq = ConvexHull(xy).equations  # rows (n_x, n_y, c): n·x + c <= 0 inside, n unit
    except Exception:  # degenerate footprint
        return np.zeros((0, 3))
    inside = np.all(G @ eq[:, :2].T + eq[:, 2] <= -inset, axis=1)
    B_W = np.column_stack([G[inside], np.full(inside.sum(), table_height)])
    X_OW = np.linalg.inv(X_0)
    return B_W @ X_OW[:3, :3].T + X_OW[:3, 3]


def base_shift(B_W: np.ndarray, seen: "callable", f: np.ndarray, max_shift: float, step: float = 0.001,
               tol: float = 0.01) -> float:
    """The least shift s in [0, ``max_shift``] (``step``) along the horizontal unit direction f (3,) at which at most
    ``tol`` of the base points B_W (B,3) (``base_points`` placed at the join) lie where the settled frames see the
    table or background (``seen(P) -> (len(P),) bool``); 0 when none does. After the topple the base faces −f, so
    a join that stops short of the landing (the lab's cartons slide beyond the pure turn about the edge) puts it
    in the empty space the frames see behind the object; the least consistent shift is a lower bound of the slide."""
    for s in np.arange(0.0, max_shift + 0.5 * step, step):
        if float(np.mean(seen(B_W + s * f))) <= tol:
            return float(s)
    return 0.0


def tip_direction(X_a: np.ndarray, X_b: np.ndarray) -> tuple[np.ndarray, float] | None:
    """The horizontal direction f (3,) an object tips toward between poses X_a and X_b (4, 4), f = h × z with h the
    horizontal part of the turn's axis, and the turn's angle (rad); None when the turn has no horizontal axis."""
    w = so3_log(X_b[:3, :3] @ X_a[:3, :3].T)
    h = np.array([w[0], w[1], 0.0])
    if np.linalg.norm(h) < 1e-6:
        return None
    return np.cross(h / np.linalg.norm(h), [0.0, 0.0, 1.0]), float(np.linalg.norm(w))


def tip_path(X_a: np.ndarray, X_b: np.ndarray, pivot: np.ndarray) -> "callable":
    """The poses of a topple between the pose X_a (4,4) before the fall and the settled pose X_b (4,4) as a turn
    about the line through ``pivot`` (3,) (the leading bottom edge at X_a, on the table, in W, m) along the axis of
    the rotation R_b R_aᵀ: ``path(u)`` (u in [0, 1]) turns X_a by u of that rotation about the line, plus u of the
    residual slide (the landing's slide beyond the pure turn, and the errors of the pivot), so that path(0) = X_a
    and path(1) = X_b. Returns the function u -> (4,4) X_WO."""
    R_a, t_a = X_a[:3, :3], X_a[:3, 3]
    w = so3_log(X_b[:3, :3] @ R_a.T)
    slide = X_b[:3, 3] - (pivot + so3_exp(w) @ (t_a - pivot))

    def path(u: float) -> np.ndarray:
        R_u = so3_exp(u * w)
        return make_X(R_u @ R_a, pivot + R_u @ (t_a - pivot) + u * slide)

    return path


def leading_pivot(B_W: np.ndarray, f: np.ndarray, table_height: float) -> np.ndarray:
    """(3,) point of the leading bottom edge (W, m): the base points B_W (B,3) (``base_points`` placed at the pose
    before the fall) moved along the horizontal unit direction f (3,) to their farthest extent along f, at their
    centre across f, on the table."""
    c = B_W.mean(0)
    p = c + (float(np.max(B_W @ f)) - float(c @ f)) * f
    p[2] = table_height
    return p


def path_keys(P_W: np.ndarray, poses: list[np.ndarray], tree, inlier_dist: float) -> list[tuple[float, float]]:
    """Per pose X_WO of ``poses`` (list of (4,4)) how well the frame's points P_W (N,3) fit the model with KD-tree
    ``tree`` (over its points in O) placed there: (fraction within ``inlier_dist``, minus the mean distance capped
    at 2 cm); larger is better."""
    keys = []
    for X in poses:
        X_OW = X_inv(X)
        d, _ = tree.query(P_W @ X_OW[:3, :3].T + X_OW[:3, 3], distance_upper_bound=0.02)
        d = np.minimum(d, 0.02)
        keys.append((float(np.mean(d < inlier_dist)), -float(np.mean(d))))
    return keys


def path_offset(X: np.ndarray, poses: list[np.ndarray], m_deg: float) -> float:
    """How far the pose X (4,4) is from the path ``poses`` (list of (4,4)): at the path pose whose rotation is
    nearest, the rotation between them (degrees) plus ``m_deg`` degrees per metre of the distance between their
    origins."""
    d = [pose_distance(X, P) for P in poses]
    k = int(np.argmin([a for _, a in d]))
    return float(d[k][1] + m_deg * d[k][0])


@dataclass
class Landing:
    g0: int  # first frame of the fast stretch (its poses are suspect)
    i: int  # the settled frame that was re-localised
    X_old: np.ndarray  # (4,4) its tracked pose before
    X_new: np.ndarray  # (4,4) the re-localised pose
    score_old: float
    score_new: float
    adopted: bool


def heights(X_WO: np.ndarray, Q_O: np.ndarray) -> np.ndarray:
    return Q_O @ X_WO[2, :3] + X_WO[2, 3]


def below_table_frac(X_WO: np.ndarray, Q_O: np.ndarray, table_height: float, margin: float) -> float:
    """Fraction of the model points (M,3) that lie more than ``margin`` below the table plane with pose X_WO."""
    if len(Q_O) == 0:
        return 0.0
    return float(np.mean(heights(X_WO, Q_O) < table_height - margin))


def pose_consistent(X_WO: np.ndarray, Q_O: np.ndarray, table_height: float, view, table_margin: float,
                    table_frac: float, seen_frac: float) -> bool:
    """False when the model Q_O (M,3) placed with X_WO has more than ``table_frac`` of its points more than
    ``table_margin`` below the table, or (``view``: a ``FreeSpace`` holding the current frame's depth with the
    identity pose, may be None) more than ``seen_frac`` of them where the current frame sees through them (its depth
    reading lies behind the point: the camera sees the table or background there). The second test is what tells a
    box slid along its own face — every frame point still on the model — from the right pose: the slid model
    covers pixels where the frame sees the table."""
    if below_table_frac(X_WO, Q_O, table_height, table_margin) > table_frac:
        return False
    if view is not None and len(Q_O):
        if float(np.mean(view.seen_through(Q_O @ X_WO[:3, :3].T + X_WO[:3, 3]))) > seen_frac:
            return False
    return True


def landed_face(Q_O: np.ndarray, N_O: np.ndarray, X: np.ndarray, table_height: float,
                cos_min: float = np.cos(np.radians(30.0)), tol: float = 0.02, base_n_O: np.ndarray | None = None,
                square_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray] | None:
    """The face of the model (Q_O, N_O (M,3), in O) that lies on the table at pose X (4,4): the points with normals
    within acos(cos_min) of −z and within ``tol`` of the table (at least 20; else None). Returns (its points (F,3)
    in O, its outward unit normal (3,) in O: the smallest principal axis of the points, oriented like their normals).
    With ``base_n_O`` (3,) and ``square_deg`` > 0, a normal within that angle of perpendicular to the base the object
    stood on at frame 0 is made perpendicular (a side of a prism standing on its base)."""
    Nw = N_O @ X[:3, :3].T
    z = Q_O @ X[2, :3] + X[2, 3]
    sel = (Nw[:, 2] < -cos_min) & (z < table_height + tol)
    if sel.sum() < 20:
        return None
    F = Q_O[sel]
    F = F[np.abs((F - np.median(F, 0)) @ N_O[sel].mean(0)) < 0.01]
    if len(F) < 20:
        return None
    _, V = np.linalg.eigh(np.cov((F - F.mean(0)).T))
    n = V[:, 0] * np.sign(V[:, 0] @ N_O[sel].mean(0))
    if base_n_O is not None and square_deg > 0:
        b = base_n_O / np.linalg.norm(base_n_O)
        if abs(n @ b) < np.sin(np.radians(square_deg)):
            n = n - (n @ b) * b
            n /= np.linalg.norm(n)
    return F, n


def flush_pose(X: np.ndarray, F_O: np.ndarray, n_O: np.ndarray, table_height: float) -> tuple[np.ndarray, float]:
    """Pose X (4,4) turned about the centroid of the face F_O (F,3) (in O, outward unit normal n_O (3,)) by the least
    rotation that lays n_O on −z, then moved vertically so that the face's median height is the table's: an object at
    rest on a flat face has that face flush with the table (two tilts and the height fixed; the yaw and the
    horizontal position kept). Returns (the pose, the tilt removed in degrees)."""
    R, t = X[:3, :3], X[:3, 3]
    Rc, ang = _lay_down(R @ n_O)
    c = (F_O @ R.T + t).mean(0)
    R2 = Rc @ R
    t2 = c + Rc @ (t - c)
    t2[2] += table_height - float(np.median(F_O @ R2[2] + t2[2]))
    return make_X(R2, t2), float(np.degrees(ang))


def planar_register(P_W: np.ndarray, X: np.ndarray, Q_O: np.ndarray, N_O: np.ndarray, tree=None, iters: int = 12,
                    dist0: float = 0.012, dist_min: float = 0.004, huber: float = 0.002,
                    w_point: float = 0.05) -> np.ndarray:
    """Pose X (4,4) of the model (Q_O, N_O (M,3)) refined by the frame's points P_W (N,3) in the motions that keep
    an object resting on the table: a turn about the vertical and a horizontal shift (3 unknowns; the tilts and the
    height stay). Robust point-to-plane residuals (Huber ``huber``) plus a small point-to-point term ``w_point``
    against sliding along planes, correspondences within a radius shrinking from ``dist0`` to ``dist_min``; ``tree``:
    a KD-tree over Q_O (built when None)."""
    from scipy.spatial import cKDTree

    if tree is None:
        tree = cKDTree(Q_O)
    R, t = X[:3, :3], X[:3, 3]
    c = P_W.mean(0)
    th, d = 0.0, np.zeros(2)
    for k in range(iters):
        rad = dist0 + (dist_min - dist0) * k / max(1, iters - 1)
        cs, sn = np.cos(th), np.sin(th)
        Rz = np.array([[cs, -sn, 0.0], [sn, cs, 0.0], [0.0, 0.0, 1.0]])
        P = (P_W - c) @ Rz.T + c + np.array([d[0], d[1], 0.0])  # frame points moved onto the fixed model
        dist, j = tree.query((P - t) @ R, distance_upper_bound=rad)  # in O
        ok = np.isfinite(dist)
        if ok.sum() < 10:
            break
        P, q, n = P[ok], Q_O[j[ok]] @ R.T + t, N_O[j[ok]] @ R.T
        r = ((P - q) * n).sum(1)
        w = np.where(np.abs(r) <= huber, 1.0, huber / np.maximum(np.abs(r), 1e-12))
        dp = P - c - np.array([d[0], d[1], 0.0])  # the turn acts before the shift
        J = np.column_stack([n[:, 1] * dp[:, 0] - n[:, 0] * dp[:, 1], n[:, 0], n[:, 1]])  # n · (e_z × dp), n_x, n_y
        A = (J * w[:, None]).T @ J
        g = (J * w[:, None]).T @ r
        # point-to-point term (horizontal components)
        e = (P - q)[:, :2]
        Jp = np.stack([np.column_stack([-dp[:, 1], np.ones(len(dp)), np.zeros(len(dp))]),
                       np.column_stack([dp[:, 0], np.zeros(len(dp)), np.ones(len(dp))])], 1)  # (K,2,3)
        A += w_point * np.einsum("kai,kaj->ij", Jp, Jp)
        g += w_point * np.einsum("kai,ka->i", Jp, e)
        step = -np.linalg.solve(A + 1e-9 * np.eye(3), g)
        th += step[0]
        d += step[1:]
        if abs(step[0]) < 1e-6 and np.linalg.norm(step[1:]) < 1e-6:
            break
    # frame points moved by S (turn th about c, shift d) fit the model at X: the object is at S⁻¹ X
    cs, sn = np.cos(th), np.sin(th)
    S = make_X(np.array([[cs, -sn, 0.0], [sn, cs, 0.0], [0.0, 0.0, 1.0]]), np.zeros(3))
    S[:3, 3] = c - S[:3, :3] @ c + np.array([d[0], d[1], 0.0])
    return X_inv(S) @ X


def still_fit(P_j: np.ndarray, P_i: np.ndarray, N_i: np.ndarray, tree=None, radius: float = 0.01
              ) -> tuple[float, float]:
    """How well frame j's object points P_j (N,3, in W) lie on frame i's object points P_i (M,3, in W) with unit
    normals N_i (M,3): (fraction of P_j with a point of P_i within ``radius``, median point-to-plane distance of
    those in metres; (0, inf) with fewer than 10). Model-free and pose-free: with a static camera an object that
    has not moved between the frames shows the same surface, so its points lie on the other frame's within the
    depth noise (0.6-1.0 mm median on the development topples), while a turn of a degree or more about an axis
    through the object moves them off it (3.6-8 mm on the turning frames of a topple). ``tree``: a KD-tree over
    P_i (built when None)."""
    from scipy.spatial import cKDTree

    if len(P_j) == 0 or len(P_i) == 0:
        return 0.0, float("inf")
    if tree is None:
        tree = cKDTree(P_i)
    d, k = tree.query(P_j, distance_upper_bound=radius)
    ok = np.isfinite(d)
    if ok.sum() < 10:
        return 0.0, float("inf")
    return float(ok.mean()), float(np.median(np.abs(((P_j[ok] - P_i[k[ok]]) * N_i[k[ok]]).sum(1))))


def side_pose(X: np.ndarray, Q_O: np.ndarray, base_n_O: np.ndarray, tol: float = 0.01) -> tuple[np.ndarray, float]:
    """Pose X (4,4) turned by the least rotation that makes the base normal ``base_n_O`` (3,) (in O: the face the
    object stood on at frame 0) horizontal, about the centroid of the model's points Q_O (M,3) within ``tol`` of its
    lowest point at X (the contact with the table): a prism lying on a side has its base vertical. Used when the face
    it lies on was never seen (``landed_face`` None), so only the tilt that turns the base is known. Returns (the
    pose, the tilt removed in degrees)."""
    R, t = X[:3, :3], X[:3, 3]
    turn = horizontal_turn(R @ (base_n_O / np.linalg.norm(base_n_O)))
    if turn is None:
        return X.copy(), 90.0
    v, s, ang = turn
    Rc = so3_exp(v / s * ang) if s > 1e-12 else np.eye(3)
    return _turn_at_contact(X, Q_O, Rc, tol), float(np.degrees(ang))


def box_rest_face(Q_O: np.ndarray, N_O: np.ndarray, base_n_O: np.ndarray, down_O: np.ndarray) -> np.ndarray | None:
    """The outward unit normal (3,) in O of the side of a box it lies on when that side was never seen: the side
    direction of the box (``box_face``: the directions at right angles of its seen flat sides, squared to the base
    normal ``base_n_O`` (3,)) nearest the downward direction ``down_O`` (3,) at the settled pose. Q_O, N_O (M,3) the
    model in O. None when the model shows no box (no flat side, or sides not at right angles)."""
    plane = box_face(Q_O, N_O, down_O / np.linalg.norm(down_O), base_n_O)
    return None if plane is None else plane[0]


def down_pose(X: np.ndarray, Q_O: np.ndarray, n_O: np.ndarray, tol: float = 0.01) -> tuple[np.ndarray, float]:
    """Pose X (4,4) turned by the least rotation that lays the unit normal ``n_O`` (3,) (in O: the face the object
    lies on) on −z, about the centroid of the model's points Q_O (M,3) within ``tol`` of its lowest point at X (the
    contact with the table): a box at rest on a face has it flat on the table (two tilts; the yaw, the horizontal
    position and the contact's height kept). ``flush_pose`` without the face's points, for a face never seen.
    Returns (the pose, the tilt removed in degrees)."""
    Rc, ang = _lay_down(X[:3, :3] @ (n_O / np.linalg.norm(n_O)))
    return _turn_at_contact(X, Q_O, Rc, tol), float(np.degrees(ang))


def _lay_down(a: np.ndarray) -> tuple[np.ndarray, float]:
    """(Rc (3,3), angle (rad)): the least rotation that lays the direction a (3,) in W on −z."""
    b = np.array([0.0, 0.0, -1.0])
    v = np.cross(a, b)
    s = float(np.linalg.norm(v))
    ang = float(np.arctan2(s, a @ b))
    return (so3_exp(v / s * ang) if s > 1e-12 else np.eye(3)), ang


def _turn_at_contact(X: np.ndarray, Q_O: np.ndarray, Rc: np.ndarray, tol: float) -> np.ndarray:
    """Pose X (4,4) turned by Rc (3,3, in W) about the centroid of the model's points Q_O (M,3) within ``tol`` (m) of
    its lowest point at X: the contact with the table stays where it is."""
    R, t = X[:3, :3], X[:3, 3]
    P = Q_O @ R.T + t
    c = P[P[:, 2] < P[:, 2].min() + tol].mean(0)
    return make_X(Rc @ R, c + Rc @ (t - c))


def has_flat_side(Q_O: np.ndarray, N_O: np.ndarray, base_n_O: np.ndarray) -> bool:
    """Whether the model (Q_O, N_O (M,3)) has a flat face (``face_plane``) among its sides, the normals within 17° of
    perpendicular to the base normal ``base_n_O`` (3,): a prism, whose base stands vertical when it lies on a side
    (not a curved body such as an egg)."""
    b = base_n_O / np.linalg.norm(base_n_O)
    side = np.abs(N_O @ b) < 0.3
    if side.sum() < 30:
        return False
    S = N_O[side]
    sub = S[:: max(1, len(S) // 300)]
    d = sub[int(np.argmax([(S @ s > np.cos(np.radians(20.0))).sum() for s in sub]))]
    return face_plane(Q_O, N_O, d, np.cos(np.radians(30.0)), 0.03) is not None


def rests_flat(Q_O: np.ndarray, N_O: np.ndarray, base_n_O: np.ndarray, down_O: np.ndarray) -> bool:
    """Whether the model (Q_O, N_O (M,3), in O) has a face to rest on: a flat side (``has_flat_side``, base normal
    ``base_n_O``) or a flat face where it lies (``face_plane`` about the downward direction ``down_O`` (3,), normals
    within 30°, at least 3 % of the points). A curved body such as an egg has neither."""
    return bool(has_flat_side(Q_O, N_O, base_n_O) or face_plane(Q_O, N_O, down_O, np.cos(np.radians(30.0)), 0.03))


def axis_extent(P_W: np.ndarray, X_WO: np.ndarray, h_O: np.ndarray, q: float = 0.005) -> tuple[float, float]:
    """(lo, hi) in m: the extent along the unit direction ``h_O`` (3,, in O) of the points P_W (N,3, in W) carried
    into O by the pose X_WO (4,4): their ``q`` and 1 − ``q`` quantiles (a few stray mask pixels do not count)."""
    s = (P_W - X_WO[:3, 3]) @ (X_WO[:3, :3] @ h_O)
    lo, hi = np.quantile(s, [q, 1.0 - q])
    return float(lo), float(hi)


def end_seen(P_W: np.ndarray, h_W: np.ndarray, depth: np.ndarray, mask: np.ndarray, K: np.ndarray, X_WC: np.ndarray,
             table_height: float, band: float = 0.004, walk_px: int = 24, look_px: int = 8,
             max_cut: float = 0.9) -> bool:
    """Whether the end of the object points P_W (N,3, in W; frame with ``depth`` (H,W) m, ``mask`` (H,W) bool,
    intrinsics K, camera pose X_WC) along the unit direction h_W (3,) is seen, not cut off by something in front of
    it. For up to 40 of the points within ``band`` (m) of the extreme along h_W: walk in the image from the point
    along h_W's image direction out of the mask (at most ``walk_px`` pixels), then look at the next ``look_px``
    pixels with a reading: the point is *cut* when one of them shows a surface nearer the camera than the point by
    more than 1 cm and more than 1 cm above the table (an occluder, the robot), when none has a reading, or when the
    walk leaves the image. The end is seen when fewer than ``max_cut`` of those points are cut (an occluder over part
    of an end face leaves its extreme seen elsewhere; one over the whole end cuts every point)."""
    H, W = depth.shape
    proj = P_W @ h_W
    idx = np.nonzero(proj > proj.max() - band)[0]
    idx = idx[:: max(1, len(idx) // 40)]
    R_CW, t_CW = X_WC[:3, :3].T, -X_WC[:3, :3].T @ X_WC[:3, 3]
    c1 = P_W[idx] @ R_CW.T + t_CW
    c2 = (P_W[idx] + 0.01 * h_W) @ R_CW.T + t_CW
    uv1 = c1[:, :2] / c1[:, 2:3] * np.diag(K)[:2] + K[:2, 2]
    uv2 = c2[:, :2] / c2[:, 2:3] * np.diag(K)[:2] + K[:2, 2]
    d = uv2 - uv1
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
    cut = 0
    for p, dk, zc in zip(uv1, d, c1[:, 2]):
        steps = np.arange(1, walk_px + look_px + 1)
        uu = np.round(p[0] + steps * dk[0]).astype(int)
        vv = np.round(p[1] + steps * dk[1]).astype(int)
        inside = (uu >= 0) & (uu < W) & (vv >= 0) & (vv < H)
        out = np.nonzero(~inside | ~mask[np.clip(vv, 0, H - 1), np.clip(uu, 0, W - 1)])[0]
        if len(out) == 0 or out[0] >= walk_px or not inside[out[0]:out[0] + look_px].all():
            cut += 1
            continue
        u2, v2 = uu[out[0]:out[0] + look_px], vv[out[0]:out[0] + look_px]
        z2 = depth[v2, u2]
        ok = z2 > 0
        if not ok.any():
            cut += 1
            continue
        P2 = backproject(depth, K, u2[ok], v2[ok])  # in C
        height = P2 @ X_WC[2, :3] + X_WC[2, 3] - table_height
        cut += bool(np.any((z2[ok] < zc - 0.01) & (height > 0.01)))
    return cut < max_cut * len(idx)


def table_end(X_WO: np.ndarray, u_O: np.ndarray, table_height: float, min_cos: float = 0.9) -> float:
    """The position (m) along the unit body direction ``u_O`` (3,, in O) of the table plane z = ``table_height`` (W)
    under the pose X_WO (4,4), for a body standing with u_O upright (its base on the table): the base end of its extent
    along u_O, which the mask's depth points do not give (the points within the table clearance are dropped and an
    occluder often hides the lower part). NaN when u_O is more than acos(``min_cos``) from the vertical in W."""
    c = float(X_WO[2, :3] @ u_O)
    if c < min_cos:
        return float("nan")
    return (table_height - float(X_WO[2, 3])) / c


def moved_along(X_WO: np.ndarray, h_O: np.ndarray, shift: float) -> np.ndarray:
    """Pose X_WO (4,4) with its origin moved by ``shift`` (m) along the body direction h_O (3,, unit, in O), taken
    in W at that pose (R h_O); the rotation kept. With ``shift`` from ``axis_shift`` the frame's extent along h_O
    (``axis_extent``) moves by −``shift``: onto the reference."""
    X = X_WO.copy()
    X[:3, 3] += shift * (X_WO[:3, :3] @ h_O)
    return X


def axis_shift(ref: np.ndarray, post: np.ndarray, len_tol: float = 0.006, spread_tol: float = 0.003,
               min_frac: float = 0.5, min_shift: float = 0.002, len_short: float | None = None) -> float | None:
    """The shift (m) along a box's axis h that puts the settled frames' ends where the frames before the fall saw
    them: ``ref`` (K,2) and ``post`` (M,2) the (lo, hi) extents along h in O (``axis_extent``) of the frames before
    the fall and of the settled frames with both ends seen (``end_seen``; rows of NaN where not). The box's middle
    along h is (lo + hi) / 2 in both: the reference is the median over ``ref``; a settled frame counts when its length
    hi − lo is within ``len_tol`` of the reference's (both ends of the same box; with ``len_short`` set, from
    ``len_short`` shorter to ``len_tol`` longer: a reference whose end is exact, such as the table under a standing
    box's base, against settled ends short by the pixels their outline loses); the shift is the median of the
    counted frames' middles minus the reference's. None (no shift) when fewer than 3 reference frames, fewer than
    ``min_frac`` of the settled frames (and fewer than 5) count, the counted frames' shifts spread (interquartile
    range) more than ``spread_tol``, or the shift is under ``min_shift`` (the measurement's own bias, about 1 mm)."""
    ref = np.asarray(ref, float).reshape(-1, 2)
    post = np.asarray(post, float).reshape(-1, 2)
    ref = ref[np.isfinite(ref).all(1)]
    if len(ref) < 3 or len(post) == 0:
        return None
    mid0, L0 = float(np.median(ref.sum(1) / 2)), float(np.median(ref[:, 1] - ref[:, 0]))
    ok = np.isfinite(post).all(1)
    d = post[ok, 1] - post[ok, 0] - L0
    ok[ok] = (d <= len_tol) & (d >= -(len_tol if len_short is None else len_short))
    if ok.sum() < max(5, min_frac * len(post)):
        return None
    c = post[ok].sum(1) / 2 - mid0
    q1, q3 = np.quantile(c, [0.25, 0.75])
    shift = float(np.median(c))
    if q3 - q1 > spread_tol or abs(shift) < min_shift:
        return None
    return shift
