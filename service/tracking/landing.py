"""Starts for fast motions that end on the table, and the table as a test of a pose (toppling landings).

A topple ends with a fast turn (the last 1–2 frames before the landing turn 14–16° each, 440 °/s) while the
occluder may hide most of the object; the tracking loop's constant-velocity start is then far off, and a frame
lost there was re-localised only from the last tracked pose and the keyframe poses (development milk_carton topple
820: lost at the landing, re-localised 70° off, never recovered). What the table imposes:

* the object cannot pass through the table: the model points Q_O (M,3) placed with a pose X_WO have heights
  z = (X_WO Q_O)_z ≥ h (table height h) up to noise; ``below_table_frac`` is the fraction below h − margin;
* the turn continues about the same screw until the object meets the table: with the body-frame step of the last
  two tracked frames S = X_b⁻¹ X_a (a screw, so S^k = Exp(k Log S) on SE(3) continues the rotation about the same
  moving axis — for a topple the edge it pivots on), the candidates of a frame g frames after a are
  X_a S^k for k = 1…g (``screw_path``), and the landing pose X_a S^{k*} with k* the first k ≥ 0 at which the model
  reaches the table (``land_on_table``; the face it falls onto is then flat on the table when the model holds
  points near that face's rim).

A pose whose model penetrates the table, or covers pixels where the current frame sees through it (the table or
background behind where the model would be; ``FreeSpace.seen_through`` with the frame's own depth), is
inconsistent (``pose_consistent``): a partly seen box slid along its own face keeps every frame point on the model
(development milk_carton topple 820 after the landing: 11 cm along the carton's axis, inlier fraction 0.7–0.9),
but its model then lies where the frame sees the table.
"""

from __future__ import annotations

import numpy as np

from service.transforms import se3_exp, se3_log


def screw_power(S: np.ndarray, k: float) -> np.ndarray:
    """S^k (4,4) on SE(3) (k real): the screw motion S continued, or a fraction of it."""
    w, u = se3_log(S)
    return se3_exp(k * w, k * u)


def screw_path(X_b: np.ndarray, X_a: np.ndarray, ks) -> list[np.ndarray]:
    """Poses X_a S^k for k in ``ks``, S = X_b⁻¹ X_a the body-frame step from the tracked frame b to a."""
    S = np.linalg.inv(X_b) @ X_a
    w, u = se3_log(S)
    return [X_a @ se3_exp(k * w, k * u) for k in ks]


def heights(X_WO: np.ndarray, Q_O: np.ndarray) -> np.ndarray:
    return Q_O @ X_WO[2, :3] + X_WO[2, 3]


def below_table_frac(X_WO: np.ndarray, Q_O: np.ndarray, table_height: float, margin: float) -> float:
    """Fraction of the model points (M,3) that lie more than ``margin`` below the table plane with pose X_WO."""
    if len(Q_O) == 0:
        return 0.0
    return float(np.mean(heights(X_WO, Q_O) < table_height - margin))


def land_on_table(X_b: np.ndarray, X_a: np.ndarray, Q_O: np.ndarray, table_height: float, k_max: float,
                  margin: float = 0.002, min_deg: float = 2.0, n_steps: int = 64) -> np.ndarray | None:
    """The pose X_a S^{k*} (4,4) at which continuing the step S = X_b⁻¹ X_a first brings the model to the table:
    k* = the smallest k in (0, k_max] at which more than 0.5 % of the model points reach ``margin`` below the table
    plane (refined by bisection). None when the step turns less than ``min_deg`` (not a fall), the model is already
    below the table at X_a, already rests on it (k* < 0.05) or never reaches it within k_max."""
    S = np.linalg.inv(X_b) @ X_a
    w, u = se3_log(S)
    if np.degrees(np.linalg.norm(w)) < min_deg or len(Q_O) == 0:
        return None

    def hits(k: float) -> bool:
        return below_table_frac(X_a @ se3_exp(k * w, k * u), Q_O, table_height, margin) > 0.005

    if hits(0.0):
        return None
    ks = np.linspace(0.0, k_max, n_steps + 1)[1:]
    lo = 0.0
    for k in ks:
        if hits(float(k)):
            hi = float(k)
            for _ in range(8):
                mid = 0.5 * (lo + hi)
                lo, hi = (lo, mid) if hits(mid) else (mid, hi)
            return X_a @ se3_exp(lo * w, lo * u) if lo >= 0.05 else None  # already on the table at X_a
        lo = float(k)
    return None


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
