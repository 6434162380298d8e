"""The spin closure's axis from data the tracking loop's swing errors did not smear (``spin_axis_from``).

The spin closure (``service.tracking.spin``) takes the symmetry axis of a body of revolution from the final model:
the keyframes' points placed with their tracked poses, refitted to the radius profile (``spin.find_axis``). A
keyframe whose pose carries a swing error (the axis' pointing; a twist about the axis leaves a surface of
revolution, hence its axis, unchanged) smears the model across the axis, and the axis with it. The estimates here
replace the direction (and the point) of that axis, in O; the decision whether the body is one of revolution stays
with the final model:

- "still": a model of the frames before the body first moves (``still_frames``), all placed with frame 0's pose,
  which defines O (the body has not moved; their own tracked rotations differ from it by the noise of an egg's
  weak rotations, 1–4°), so the points carry no pose error at all; the body is seen from one side (a partial model), its axis
  the best radius-profile fit (``spin.profile_axis``) from the final model's axis and from every rotation
  eigen-axis of the partial model (``spin.profile_starts``).
- "lying": a body of revolution lying on the table has its axis horizontal: over the frames where the final
  model's axis lies within ``LIE_DEG`` of the horizontal and the body does not move fast, a minimises
  Σ (ẑ_W · R_WO a)² — the smallest eigenvector of Σ u uᵀ, u = R_WOᵀ ẑ_W (``lying_axis``).
The point c of the axis: "still" its own; "lying" the radius-profile fit of the final model with the direction held
(``profile_point``).

Measured on development egg topples (docs/tracking.md "The spin closure's axis from data the loop's swing did not
smear"): both are further from the true axis than the final model's (median 13–16° against 4–5°: the still egg is
a shallow cap whose radius profile does not pin the axis; the lying frames' vertical carries the poses' swing), and
even the true axis does not repair the loop's swing; off by default.
"""

from __future__ import annotations

import numpy as np

from service.tracking.spin import fast_frames, profile_axis, profile_starts
from service.transforms import rotation_angle

LIE_DEG = 20.0  # "lying": the final model's axis within this of the horizontal
STILL_DEG = 8.0  # "still": frames before the tracked rotation from frame 0 first exceeds this ...
STILL_MOVE = 0.003  # ... or the tracked position moves by this (m)


def still_frames(X_WO: np.ndarray, deg: float = STILL_DEG, move: float = STILL_MOVE) -> np.ndarray:
    """Indices of the frames 0 … k−1 before the poses X_WO (N,4,4) first turn by more than ``deg`` from frame 0 or
    move by more than ``move`` (m)."""
    R0 = X_WO[0, :3, :3]
    for i in range(1, len(X_WO)):
        ang = np.degrees(rotation_angle(R0.T @ X_WO[i, :3, :3]))
        if ang > deg or np.linalg.norm(X_WO[i, :3, 3] - X_WO[0, :3, 3]) > move:
            return np.arange(i)
    return np.arange(len(X_WO))


def profile_point(Q: np.ndarray, a: np.ndarray, c0: np.ndarray) -> np.ndarray:
    """A point c (3,) in O of the axis with direction a (3,) that best fits the radius profile of Q (M,3) from c0."""
    return profile_axis(Q, a, c0, fixed_dir=True)[1]


def still_axis(P_O: np.ndarray, N_O: np.ndarray, a0: np.ndarray, c0: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, float]:
    """(a, c, rms) in O: the best radius-profile fit of the partial model P_O, N_O (M,3) from (a0, c0) and from its
    own rotation eigen-axes (``spin.profile_starts``)."""
    best = profile_axis(P_O, a0, c0)
    for s0, p0 in profile_starts(P_O, N_O):
        r = profile_axis(P_O, s0, p0)
        if r[2] < best[2]:
            best = r
    return best


def lying_axis(X_WO: np.ndarray, a0: np.ndarray, lie_deg: float = LIE_DEG) -> tuple[np.ndarray, int]:
    """(a (3,) in O, frames used): the unit a minimising Σ (ẑ_W · R_WO(i) a)² over the frames whose axis a0 (the
    final model's) lies within ``lie_deg`` of the horizontal and which are not in a fast stretch
    (``spin.fast_frames``); a0 itself when fewer than 10 frames qualify. Sign as a0."""
    U = X_WO[:, 2, :3]  # rows: R_WO(i)ᵀ ẑ_W, the vertical of W in O
    lying = np.abs(U @ a0) < np.sin(np.radians(lie_deg))
    use = lying & ~fast_frames(X_WO)
    if use.sum() < 10:
        return a0, int(use.sum())
    w, V = np.linalg.eigh(U[use].T @ U[use])
    a = V[:, 0]
    return (a if a @ a0 >= 0 else -a), int(use.sum())
