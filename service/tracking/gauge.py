"""Gauge of the body frame from the frames at rest before the robot reaches the object.

The final poses are registrations X̂_i of every frame to the merged model M; the body frame O is then moved by the
constant offset D = X̂_0⁻¹ X_0 so that X_WO(0) keeps its definition X_0 (``tracker._regauge``). The reported
motion of frame i relative to frame 0 is X̂_0⁻¹ X̂_i, so an error e_0 of frame 0's single registration is common
to every other frame. Frame 0 is not a typical frame: on the development l_block pivot 812, whose block rests for
its first 20+ frames, frames 1–15 registered to M sit 0.4–0.6° (about x and y) from frame 0's registration, and a
direct registration of each of them to frame 0's points reports the same 0.5° "motion" — the observation of
frame 0 differs from the later ones of the same still object (depth noise, occluder), not the registrations.

With ``gauge_frames`` = n > 0, frames known to show the object still — the first tracked frames, up to n, before
the end-effector sphere comes within ``gauge_ee_margin`` of the model (an object on the table moves only when
pushed; sessions without robot data: none) and within ``gauge_max_deg`` / ``gauge_max_dist`` of frame 0's pose
— share frame 0's true pose, so each X̂_j is an estimate of X̂_0 too, and

    X̂_0 = robust mean of {X̂_0 (frame 0's registration), X̂_j (rest frames)}:
    rotation R̄ = R_ref Exp(median_j Log(R_refᵀ R_j)) (median per component of the tangent vectors about the first),
    translation the component-wise median.
"""

from __future__ import annotations

import numpy as np

from service.transforms import make_X, so3_exp, so3_log


def robust_mean_pose(Xs: list[np.ndarray]) -> np.ndarray:
    """Robust mean of poses (K,4,4): rotation by the component-wise median of the tangent vectors about the first
    pose's rotation, translation by the component-wise median."""
    R0 = Xs[0][:3, :3]
    w = np.median(np.stack([so3_log(R0.T @ X[:3, :3]) for X in Xs]), axis=0)
    t = np.median(np.stack([X[:3, 3] for X in Xs]), axis=0)
    return make_X(R0 @ so3_exp(w), t)


def rest_frames(X: np.ndarray, tracked: np.ndarray, n_points: np.ndarray, p_WE: np.ndarray | None, ee_radius: float,
                model_tree, n: int, margin: float, max_deg: float, max_dist: float, min_points: int) -> list[int]:
    """Indices j ≥ 1 of at most n frames showing the object still: consecutive from frame 1 up to the first frame
    whose end-effector centre p_WE[j] (N,3) comes within ee_radius + margin of the model (KD-tree ``model_tree`` over
    the model points in O, the centre mapped to O with X[j]) or whose pose X[j] is farther than max_deg / max_dist
    from X[0]; untracked frames and frames with fewer than min_points points are skipped. Empty without robot
    data (p_WE None)."""
    from service.transforms import X_inv, pose_distance

    out: list[int] = []
    if p_WE is None or len(p_WE) != len(X):
        return out
    for j in range(1, len(X)):
        if len(out) >= n:
            break
        Xi = X_inv(X[j])
        d, _ = model_tree.query(Xi[:3, :3] @ p_WE[j] + Xi[:3, 3])
        if d < ee_radius + margin:
            break  # the robot may touch the object from here on
        dist, ang = pose_distance(X[0], X[j])
        if ang > max_deg or dist > max_dist:
            break
        if tracked[j] and n_points[j] >= min_points:
            out.append(j)
    return out


def gauge_pose(X0_hat: np.ndarray | None, X: np.ndarray, rest: list[int]) -> np.ndarray | None:
    """X̂_0 (4,4): robust mean of frame 0's registration X0_hat (None when it failed) and the final poses X[j] of the
    rest frames; None when there is no estimate."""
    ests = ([] if X0_hat is None else [X0_hat]) + [X[j] for j in rest]
    return robust_mean_pose(ests) if ests else None
