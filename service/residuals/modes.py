"""Contact-mode classification and residual statistics by mode.

Per frame k of an observed trajectory (poses X_WO (N,4,4), backward-difference velocities):
- ``φ_T[k] = min_i (R p_i + p)_z − z_table`` over the model's collision vertices p_i (gap to table);
- ``φ_E[k]`` = signed distance of the sphere centre to the convex pieces (max over face planes,
  exact on faces, a lower bound near edges) minus the radius (∞ without a robot);
- ``Δv[k] = min(|v[k+1] − v[k] − g dt|, |v[k+1] − v[k]|)`` (velocity jump explained neither by free
  fall nor by resting support; at 30 Hz g dt alone is 0.33 m/s).

Mode: ``robot_contact`` if φ_E < tol; else, touching the table (φ_T < tol): ``impact`` if
Δv > impact_dv, ``rest`` if |v| and |ω|·radius (central differences over ±2 frames, which keeps
tracking noise below the threshold) are below rest_speed, ``sliding`` otherwise (any
moving contact: sliding, rolling, pivoting); ``free_flight`` when nothing touches.

The contact stage's ``StepResiduals`` rows are classified from their own gaps and impulses
(impulse_ee > 0 → robot contact, impulse_table > m·impact_dv → impact, …) and summarised per
mode (mean |residual| of the linear and angular parts).

Kinematic statistics for the effect signatures (see ``effects.py``): per trajectory, the first run of
≥ 5 free-flight frames gets a quadratic fit p(t) ≈ p₀ + v t + ½ a t² and r(t) ≈ ω t + ½ α t² for the
body rotation vector r = Log(R₀ᵀ R); medians over trajectories of a (gravity, tilt), of
−a_h·v_h/|v_h|² (linear damping rate) and −α·ω/|ω|² (angular damping rate). At the first impact,
``rebound_ratio`` = max(v_z over the 3 frames after) / (−v_z before). At rest, ``gap_mean`` = mean
φ_T. While sliding, ``mu_apparent`` = median over sliding runs (≥ 5 frames, quadratic fit of the
horizontal position) of |a_h|/g.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull

from service.contact.types import StepResiduals
from service.model import ObjectModel
from service.residuals.types import MODES, ObservedTrajectory, ResidualConfig, RobotPath
from service.transforms import quat_to_rotvec, mat_to_quat

G = 9.81
FREE, SLIDING, ROBOT, IMPACT, REST = range(5)


def collision_vertices(model: ObjectModel) -> np.ndarray:
    """(V,3) vertices of all collision pieces (visual mesh when there are none), frame O."""
    pieces = [np.asarray(m.vertices, float) for m in model.collision if len(m.vertices)]
    return np.concatenate(pieces, 0) if pieces else np.asarray(model.visual.vertices, float)


def object_radius(model: ObjectModel) -> float:
    """Largest distance of a collision vertex from the CoM, m (the rotation-to-metres scale)."""
    V = collision_vertices(model)
    return float(np.max(np.linalg.norm(V - np.asarray(model.com_O, float), axis=1)))


def _hull_planes(model: ObjectModel) -> list[np.ndarray]:
    planes = []
    pieces = [np.asarray(m.vertices, float) for m in model.collision if len(m.vertices) >= 4] or [
        np.asarray(model.visual.vertices, float)
    ]
    for V in pieces:
        planes.append(ConvexHull(V).equations)  # (F,4): n·x + d <= 0 inside
    return planes


def table_gaps(model: ObjectModel, X_WO: np.ndarray, table_height: float) -> np.ndarray:
    """(N,) signed gap of the lowest collision vertex to the table, m."""
    V = collision_vertices(model)
    z = np.einsum("nj,vj->nv", X_WO[:, 2, :3], V) + X_WO[:, 2, 3][:, None]
    return z.min(1) - table_height


def sphere_gaps(model: ObjectModel, X_WO: np.ndarray, p_WE: np.ndarray, radius: float) -> np.ndarray:
    """(N,) signed gap object–sphere, m (face-plane distance of the centre minus the radius)."""
    R = X_WO[:, :3, :3]
    p_O = np.einsum("nji,nj->ni", R, p_WE - X_WO[:, :3, 3])  # R^T (p_WE - p)
    best = np.full(len(X_WO), np.inf)
    for eq in _hull_planes(model):
        d = (p_O @ eq[:, :3].T + eq[:, 3]).max(1)
        best = np.minimum(best, d)
    return best - radius


def velocities(traj: ObservedTrajectory) -> tuple[np.ndarray, np.ndarray]:
    """Backward-difference (N,3) v_WO_W and w_WO_O (given ones, else from the poses)."""
    X = np.asarray(traj.X_WO, float)
    t = np.asarray(traj.t, float)
    if traj.v_WO_W is not None and traj.w_WO_O is not None:
        return np.asarray(traj.v_WO_W, float), np.asarray(traj.w_WO_O, float)
    dt = np.diff(t)
    v = np.zeros((len(t), 3))
    w = np.zeros((len(t), 3))
    if len(t) > 1:
        v[1:] = np.diff(X[:, :3, 3], axis=0) / dt[:, None]
        dR = np.swapaxes(X[:-1, :3, :3], 1, 2) @ X[1:, :3, :3]
        w[1:] = quat_to_rotvec(mat_to_quat(dR)) / dt[:, None]
        v[0], w[0] = v[1], w[1]
    return v, w


def smoothed_speeds(t: np.ndarray, X: np.ndarray, half: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """(N,) linear and angular speeds from central differences over ±``half`` frames (noise-robust)."""
    n = len(t)
    if n < 2:
        return np.zeros(n), np.zeros(n)
    i = np.arange(n)
    a, b = np.clip(i - half, 0, n - 1), np.clip(i + half, 0, n - 1)
    dt = np.maximum(t[b] - t[a], 1e-9)
    v = np.linalg.norm(X[b, :3, 3] - X[a, :3, 3], axis=1) / dt
    dR = np.swapaxes(X[a, :3, :3], 1, 2) @ X[b, :3, :3]
    w = np.linalg.norm(quat_to_rotvec(mat_to_quat(dR)), axis=1) / dt
    return v, w


def _runs(ok: np.ndarray, min_len: int) -> list[tuple[int, int]]:
    """Maximal runs [i, j) of True of length >= min_len."""
    out, i, n = [], 0, len(ok)
    while i < n:
        if ok[i]:
            j = i
            while j < n and ok[j]:
                j += 1
            if j - i >= min_len:
                out.append((i, j))
            i = j
        else:
            i += 1
    return out


def classify(
    model: ObjectModel,
    traj: ObservedTrajectory,
    table_height: float,
    robot: RobotPath | None,
    cfg: ResidualConfig,
) -> np.ndarray:
    """(N,) int mode index into ``MODES`` for every frame."""
    X = np.asarray(traj.X_WO, float)
    t = np.asarray(traj.t, float)
    n = len(t)
    v, w = velocities(traj)
    phi_t = table_gaps(model, X, table_height)
    if robot is not None:
        pe = np.stack([np.interp(t, robot.t, robot.p_WE[:, i]) for i in range(3)], 1)
        phi_e = sphere_gaps(model, X, pe, robot.radius)
    else:
        phi_e = np.full(n, np.inf)
    dt = np.diff(t, append=t[-1] + (t[-1] - t[-2] if n > 1 else 1.0))
    jump = np.zeros(n)
    if n > 1:
        raw = np.diff(v, axis=0)
        dv = raw - np.array([0.0, 0.0, -G]) * dt[:-1, None]
        # neither free fall (Δv = g dt) nor support (Δv = 0) explains the jump
        jump[:-1] = np.minimum(np.linalg.norm(dv, axis=1), np.linalg.norm(raw, axis=1))
    rad = object_radius(model)
    vs, ws = smoothed_speeds(t, X)
    slow = (vs < cfg.rest_speed) & (ws * rad < cfg.rest_speed)
    touch = phi_t < cfg.contact_tol_m
    mode = np.full(n, FREE)
    mode[touch] = SLIDING
    mode[touch & slow] = REST
    mode[touch & (jump > cfg.impact_dv)] = IMPACT
    mode[phi_e < cfg.contact_tol_m] = ROBOT
    return mode


def classify_steps(res: StepResiduals, mass: float, cfg: ResidualConfig) -> np.ndarray:
    """(S,) mode index of each contact-stage transition, from its gaps and impulses."""
    n = len(res.step)
    mode = np.full(n, FREE)
    touch = (np.asarray(res.phi_table) < cfg.contact_tol_m) | (np.asarray(res.impulse_table) > 0)
    lin = np.linalg.norm(np.asarray(res.dv_observed)[:, 3:], axis=1)
    mode[touch] = SLIDING
    mode[touch & (lin < cfg.rest_speed * 0.25)] = REST
    mode[np.asarray(res.impulse_table) > mass * cfg.impact_dv] = IMPACT
    mode[(np.asarray(res.phi_ee) < cfg.contact_tol_m) | (np.asarray(res.impulse_ee) > 0)] = ROBOT
    return mode


def _first_free_run(mode: np.ndarray, tracked: np.ndarray, min_len: int = 5) -> tuple[int, int] | None:
    runs = _runs((mode == FREE) & tracked, min_len)
    return runs[0] if runs else None


def mode_statistics(
    model: ObjectModel,
    trajs: tuple[ObservedTrajectory, ...],
    modes: list[np.ndarray],
    table_height: float,
    step_residuals: StepResiduals | None,
    cfg: ResidualConfig,
) -> dict[str, dict[str, float]]:
    """Residual statistics per mode (``MODES`` keys), the inputs of the effect signatures."""
    stats: dict[str, dict[str, float]] = {m: {} for m in MODES}
    acc, lin_rate, ang_rate, rebound, gaps, mu_app = [], [], [], [], [], []
    counts = np.zeros(len(MODES), int)
    for traj, mode in zip(trajs, modes):
        X = np.asarray(traj.X_WO, float)
        t = np.asarray(traj.t, float)
        tracked = np.ones(len(t), bool) if traj.tracked is None else np.asarray(traj.tracked, bool)
        counts += np.bincount(mode[tracked], minlength=len(MODES))
        v, w = velocities(traj)
        run = _first_free_run(mode, tracked)
        if run is not None:
            a, b = run
            tau = t[a:b] - t[a]
            A = np.stack([np.ones_like(tau), tau, 0.5 * tau**2], 1)
            coef, *_ = np.linalg.lstsq(A, X[a:b, :3, 3], rcond=None)
            acc.append(coef[2])
            vh = coef[1][:2]
            if np.dot(vh, vh) > 0.04:
                lin_rate.append(-np.dot(coef[2][:2], vh) / np.dot(vh, vh))
            dR = np.swapaxes(X[a, :3, :3], 0, 1)[None] @ X[a:b, :3, :3]
            r = quat_to_rotvec(mat_to_quat(dR))
            cr, *_ = np.linalg.lstsq(A, r, rcond=None)
            if np.dot(cr[1], cr[1]) > 1.0 and np.linalg.norm(r[-1]) < 2.5:
                ang_rate.append(-np.dot(cr[2], cr[1]) / np.dot(cr[1], cr[1]))
            # first impact after the free run
            if b < len(t) and mode[b] in (IMPACT, SLIDING, REST) and v[b - 1, 2] < -0.2:
                after = v[b + 1 : b + 4, 2]
                if len(after):
                    rebound.append(max(float(after.max()), 0.0) / -v[b - 1, 2])
        rest = (mode == REST) & tracked
        if rest.any():
            gaps.append(table_gaps(model, X[rest], table_height))
        for a, b in _runs((mode == SLIDING) & tracked, 5):
            tau = t[a:b] - t[a]
            A = np.stack([np.ones_like(tau), tau, 0.5 * tau**2], 1)
            coef, *_ = np.linalg.lstsq(A, X[a:b, :2, 3], rcond=None)
            if np.linalg.norm(coef[1]) > cfg.sliding_speed:
                mu_app.append(float(np.linalg.norm(coef[2]) / G))
    for i, m in enumerate(MODES):
        stats[m]["frames"] = int(counts[i])
    ff = stats["free_flight"]
    if acc:
        A = np.median(np.stack(acc), 0)
        ff.update(acc_x=float(A[0]), acc_y=float(A[1]), acc_z=float(A[2]), n_fits=len(acc))
    if lin_rate:
        ff["lin_damping_rate"] = float(np.median(lin_rate))
    if ang_rate:
        ff["ang_damping_rate"] = float(np.median(ang_rate))
    if rebound:
        stats["impact"].update(rebound_ratio=float(np.median(rebound)), n_impacts=len(rebound))
    if gaps:
        g = np.concatenate(gaps)
        stats["rest"].update(gap_mean=float(np.mean(g)), gap_median=float(np.median(g)))
    if mu_app:
        stats["sliding"].update(mu_apparent=float(np.median(mu_app)), mu_model=float(model.friction.object_table))
    if step_residuals is not None and len(step_residuals.step):
        sm = classify_steps(step_residuals, model.mass, cfg)
        r = np.asarray(step_residuals.residual, float)
        for i, m in enumerate(MODES):
            sel = sm == i
            stats[m]["steps"] = int(sel.sum())
            if sel.any():
                stats[m]["res_ang_norm"] = float(np.mean(np.linalg.norm(r[sel, :3], axis=1)))
                stats[m]["res_lin_norm"] = float(np.mean(np.linalg.norm(r[sel, 3:], axis=1)))
                stats[m]["res_lin_tangential"] = float(np.mean(np.linalg.norm(r[sel, 3:5], axis=1)))
                stats[m]["res_lin_mean"] = [float(x) for x in r[sel, 3:].mean(0)]
    return stats

