"""Evaluation of a processed session against its ground truth and by open-loop dynamics (method-notes §8).

- Tracking: with G the true body frame, the fixed offset ``X_OG = X_WO(k0)⁻¹ X_WG(k0)`` from the first tracked
  frame k0; per frame the translation error ‖p(X_WO X_OG) − p(X_WG)‖ and the geodesic angle of
  ``R_WGᵀ R_WO R_OG``; median and max over tracked frames.
- Geometry: for each method's mesh in O, the true mesh is brought into O by ``X_OG0`` (above; or the
  centroid difference without poses) refined by ICP onto the estimate (evaluation only); chamfer (two-way
  mean, m) and volumetric IoU (``service.evaluation.geometry``).
- Dynamics: open-loop rollouts (``service.sim``) from the tracked first pose, replaying the robot from the
  recorded commands (impedance) or else the recorded sphere path (kinematic), for each method's model and
  for the true geometry (true mesh placed in O by ``X_OG0``, inertia of the fused model). Against the tracked
  trajectory: mean position error (m), mean rotation error (deg), time before divergence (first frame with
  error > 0.10 m or > 45°; if never, last time + 1 ms), and contact agreement with ``contacts.csv``:
  ``contact_iou`` = fraction of frames where simulated and annotated contact agree (as the reference code's
  ``binary_iou``), ``contact_iou_jaccard`` = |A∩B| / |A∪B|.

A metric that cannot be computed is None with the reason in ``<metric>_reason`` (or ``reason`` for a whole
group).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from service.evaluation.geometry import chamfer, icp, sample_surface, voxel_iou
from service.evaluation.ground_truth import GroundTruth, load_ground_truth
from service.evaluation.types import METHODS, EvaluationConfig, EvaluationInputs, EvaluationOutputs
from service.mesh import Mesh
from service.model import ObjectModel
from service.sim import RobotPath, rollout
from service.transforms import X_inv, make_X, pose_errors, rotation_angle, so3_log, transform_points

GT_METHOD = "ground_truth_geometry"


def _check_inputs(inp: EvaluationInputs) -> None:
    N = len(inp.t)
    if np.shape(inp.X_WO) != (N, 4, 4):
        raise ValueError(f"X_WO must be (N,4,4) with N = len(t) = {N}, got {np.shape(inp.X_WO)}")
    if np.shape(inp.tracked) != (N,):
        raise ValueError(f"tracked must be (N,) with N = {N}, got {np.shape(inp.tracked)}")


def _match_frames(t: np.ndarray, t_gt: np.ndarray, tol: float) -> np.ndarray:
    """Index into t_gt for every t (−1 where no ground-truth time lies within tol)."""
    j = np.clip(np.searchsorted(t_gt, t), 1, max(len(t_gt) - 1, 1))
    j = np.where(np.abs(t_gt[j - 1] - t) <= np.abs(t_gt[np.minimum(j, len(t_gt) - 1)] - t), j - 1, j)
    j = np.minimum(j, len(t_gt) - 1)
    return np.where(np.abs(t_gt[j] - t) <= tol, j, -1)


# ------------------------------------------------------------------------------------------- tracking
def tracking_metrics(inp: EvaluationInputs, gt: GroundTruth | None) -> tuple[dict, dict, np.ndarray | None]:
    keys = ("rot_err_deg_median", "rot_err_deg_max", "trans_err_m_median", "trans_err_m_max")
    null = {k: None for k in keys}
    if gt is None or gt.X_WG is None:
        return {**null, "reason": "no ground_truth/poses.csv in the session"}, {}, None
    dt_frame = float(np.median(np.diff(inp.t))) if len(inp.t) > 1 else 1.0
    j = _match_frames(np.asarray(inp.t, float), gt.t, 0.25 * dt_frame)
    ok = np.asarray(inp.tracked, bool) & (j >= 0)
    if not ok.any():
        return {**null, "reason": "no tracked frame has a ground-truth pose at its time"}, {}, None
    k0 = int(np.flatnonzero(ok)[0])
    X_OG = X_inv(inp.X_WO[k0]) @ gt.X_WG[j[k0]]
    X_est = inp.X_WO[ok] @ X_OG
    dt, dr = pose_errors(X_est, gt.X_WG[j[ok]])
    dr = np.degrees(dr)
    out = {"rot_err_deg_median": float(np.median(dr)), "rot_err_deg_max": float(dr.max()),
           "trans_err_m_median": float(np.median(dt)), "trans_err_m_max": float(dt.max()),
           "frames_compared": int(ok.sum())}
    t_err = np.full(len(inp.t), np.nan)
    r_err = np.full(len(inp.t), np.nan)
    t_err[ok], r_err[ok] = dt, dr
    return out, {"tracking/trans_err_m": t_err, "tracking/rot_err_deg": r_err}, X_OG


# ------------------------------------------------------------------------------------------- geometry
def _initial_X_OG(est: Mesh, gt_mesh: Mesh, X_OG0: np.ndarray | None) -> np.ndarray:
    if X_OG0 is not None:
        return X_OG0
    return make_X(np.eye(3), np.asarray(est.vertices).mean(0) - np.asarray(gt_mesh.vertices).mean(0))


def geometry_metrics(meshes: dict[str, Mesh], gt: GroundTruth | None, X_OG0: np.ndarray | None,
                     cfg: EvaluationConfig) -> tuple[dict, dict]:
    out: dict = {}
    series: dict = {}
    for name in [m for m in METHODS if m in meshes] + [m for m in meshes if m not in METHODS]:
        est = meshes[name]
        if gt is None or gt.mesh is None:
            out[name] = {"chamfer_m": None, "iou": None, "reason": "no ground_truth/mesh.obj in the session"}
            continue
        if est is None or est.is_empty:
            out[name] = {"chamfer_m": None, "iou": None, "reason": f"the {name} mesh is empty"}
            continue
        A = sample_surface(est, cfg.n_samples, cfg.seed, split_components=True)
        G = sample_surface(gt.mesh, cfg.n_samples, cfg.seed + 1)
        X0 = _initial_X_OG(est, gt.mesh, X_OG0)
        res = icp(G, A, X0, max_corr=cfg.icp_max_corr, max_iter=cfg.icp_max_iter)
        X_OG = res.X
        gt_O = Mesh(transform_points(X_OG, np.asarray(gt.mesh.vertices, float)), np.asarray(gt.mesh.faces))
        cd = chamfer(A, transform_points(X_OG, G))
        vi = voxel_iou(est, gt_O, pitch=cfg.iou_pitch, max_res=cfg.iou_max_res)
        shift = X_inv(X0) @ X_OG
        out[name] = {
            "chamfer_m": cd,
            "iou": None if np.isnan(vi.iou) else float(vi.iou),
            "volume_m3": float(vi.volume_a),
            "volume_true_m3": float(vi.volume_b),
            "alignment": {"icp_rmse_m": res.rmse, "icp_fitness": res.fitness, "iterations": res.iterations,
                          "shift_m": float(np.linalg.norm(shift[:3, 3])),
                          "shift_deg": float(np.degrees(rotation_angle(shift[:3, :3])))},
        }
        series[f"geometry/{name}/X_OG"] = X_OG
    return out, series


# ------------------------------------------------------------------------------------------- dynamics
def collision_pieces(mesh: Mesh, how: str) -> tuple[Mesh, ...]:
    """Convex pieces of a mesh: "decompose" = the bundle's own decomposition (exact hull when nearly convex,
    else V-HACD), "hull" = its convex hull."""
    if how == "decompose":
        from service.export.collision import make_collision_pieces
        from service.export.types import ExportConfig

        return tuple(make_collision_pieces(mesh, ExportConfig.fast()))
    if how == "hull":
        import trimesh

        v = np.asarray(mesh.vertices, float)
        return (Mesh.from_trimesh(trimesh.Trimesh(v, np.zeros((0, 3), np.int64), process=False).convex_hull),)
    raise ValueError(f"collision must be 'decompose' or 'hull', got {how!r}")


def _with_pieces(model: ObjectModel, how: str) -> ObjectModel:
    if model.collision and not all(c.is_empty for c in model.collision):
        return model
    if model.visual is None or model.visual.is_empty:
        raise ValueError("model has neither collision pieces nor a visual mesh")
    return replace(model, collision=collision_pieces(model.visual, how))


def true_geometry_model(gt_mesh: Mesh, X_OG: np.ndarray, like: ObjectModel, how: str = "decompose") -> ObjectModel:
    """The true shape placed in O (convex pieces as ``collision_pieces``) with the inertia, friction and effects
    of ``like``."""
    v = transform_points(X_OG, np.asarray(gt_mesh.vertices, float))
    m = Mesh(v, np.asarray(gt_mesh.faces, np.int64))
    return ObjectModel(visual=m, collision=collision_pieces(m, how), mass=like.mass, mass_declared=like.mass_declared,
                       com_O=like.com_O, inertia_O=like.inertia_O, friction=like.friction, effects=dict(like.effects))


def initial_velocity(t: np.ndarray, X_WO: np.ndarray, k0: int, k1: int | None, rest_m: float = 0.0,
                     rest_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Backward difference between tracked frames k0 and k1 > k0: v of O's origin in W, ω in O axes.

    Zero when the motion between the two frames is below (rest_m, rest_deg), i.e. within tracking noise."""
    if k1 is None:
        return np.zeros(3), np.zeros(3)
    h = t[k1] - t[k0]
    dp = X_WO[k1, :3, 3] - X_WO[k0, :3, 3]
    r = so3_log(X_WO[k0, :3, :3].T @ X_WO[k1, :3, :3])
    if np.linalg.norm(dp) < rest_m and np.degrees(np.linalg.norm(r)) < rest_deg:
        return np.zeros(3), np.zeros(3)
    return dp / h, r / h


def _robot_path(inp: EvaluationInputs, cfg: EvaluationConfig) -> tuple[RobotPath, str]:
    s = inp.session
    has_cmd = s.robot_cmd_WE is not None
    mode = cfg.robot_mode
    if mode == "auto":
        mode = "impedance" if has_cmd else "kinematic"
    if mode == "impedance" and not has_cmd:
        raise ValueError("robot_mode 'impedance' needs recorded commands (cmd_x,cmd_y,cmd_z in robot.csv)")
    p = s.robot_cmd_WE if mode == "impedance" else s.robot_p_WE
    t = np.asarray(s.robot_t, float)
    p = np.asarray(p, float)
    keep = np.concatenate([[True], np.diff(t) > 0])
    return RobotPath(t[keep], p[keep], commanded=mode == "impedance"), mode


def trajectory_metrics(t: np.ndarray, X_sim: np.ndarray, X_ref: np.ndarray, valid: np.ndarray,
                       div_pos: float, div_rot_deg: float) -> tuple[dict, np.ndarray, np.ndarray]:
    """Mean errors and time before divergence of a rollout against the reference at valid frames."""
    dp, dr = pose_errors(X_sim, X_ref)
    dr = np.degrees(dr)
    dp = np.where(valid, dp, np.nan)
    dr = np.where(valid, dr, np.nan)
    bad = valid & ((dp > div_pos) | (dr > div_rot_deg))
    tbd = float(t[np.argmax(bad)] - t[0]) if bad.any() else float(t[valid][-1] - t[0] + 1e-3)
    return ({"pos_err_m": float(np.nanmean(dp)), "rot_err_deg": float(np.nanmean(dr)),
             "time_before_divergence_s": tbd,
             "time_before_divergence_frac": tbd / max(float(t[valid][-1] - t[0]), 1e-9)}, dp, dr)


def contact_scores(sim: np.ndarray, ann: np.ndarray) -> dict:
    union = int((sim | ann).sum())
    return {"contact_iou": float((sim == ann).mean()),
            "contact_iou_jaccard": float((sim & ann).sum() / union) if union else None,
            **({} if union else {"contact_iou_jaccard_reason": "no contact in either the rollout or the annotation"})}


def dynamics_metrics(inp: EvaluationInputs, gt: GroundTruth | None, X_OG0: np.ndarray | None,
                     cfg: EvaluationConfig, progress: Callable[[float, str], None] | None = None) -> tuple[dict, dict]:
    s = inp.session
    t = np.asarray(inp.t, float)
    tracked = np.asarray(inp.tracked, bool)
    out: dict = {}
    series: dict = {}
    models: dict[str, ObjectModel] = {m: inp.models[m] for m in METHODS if m in inp.models}
    models.update({m: v for m, v in inp.models.items() if m not in models})
    if not tracked.any():
        for m in list(models) + [GT_METHOD]:
            out[m] = {"pos_err_m": None, "rot_err_deg": None, "time_before_divergence_s": None, "contact_iou": None,
                      "reason": "no tracked frame to start from or compare with"}
        return out, series
    k0 = int(np.flatnonzero(tracked)[0])
    nxt = np.flatnonzero(tracked[k0 + 1 :])
    k1 = k0 + 1 + int(nxt[0]) if (cfg.initial_velocity == "finite_difference" and len(nxt)) else None
    v0, w0 = initial_velocity(t, inp.X_WO, k0, k1, cfg.rest_translation_m, cfg.rest_rotation_deg)
    path, mode = _robot_path(inp, cfg)
    sim_cfg = replace(cfg.sim, robot_mode=mode)
    t_out = t[k0:]
    valid = tracked[k0:]
    X_ref = inp.X_WO[k0:]
    ann = gt.contact_at(t_out) if gt is not None and gt.contacts is not None else None
    series["dynamics/t"] = t_out
    series["dynamics/tracked_p_WO"] = np.where(valid[:, None], X_ref[:, :3, 3], np.nan)
    if ann is not None:
        series["dynamics/annotated_contact"] = ann

    like = models.get("fused") or next(iter(models.values()), None)
    if gt is not None and gt.mesh is not None and like is not None:
        X_OG = X_OG0 if X_OG0 is not None else _initial_X_OG(like.visual, gt.mesh, None)
        models[GT_METHOD] = true_geometry_model(gt.mesh, X_OG, like, cfg.collision)
    else:
        out[GT_METHOD] = {"pos_err_m": None, "rot_err_deg": None, "time_before_divergence_s": None, "contact_iou": None,
                          "reason": "no ground_truth/mesh.obj (or no model to take the inertia from)"}

    for i, (name, model) in enumerate(models.items()):
        if progress:
            progress(i / max(len(models), 1), f"rollout {name}")
        try:
            model = _with_pieces(model, cfg.collision)
            r = rollout(model, inp.X_WO[k0], v0, w0, path, s.table_height, s.ee_radius, sim_cfg, t_out=t_out)
        except ValueError as e:
            out[name] = {"pos_err_m": None, "rot_err_deg": None, "time_before_divergence_s": None, "contact_iou": None,
                         "reason": f"rollout failed: {e}"}
            continue
        metrics, dp, dr = trajectory_metrics(t_out, r.X_WO, X_ref, valid, cfg.div_pos_m, cfg.div_rot_deg)
        if ann is not None:
            metrics.update(contact_scores(r.contact_active, ann))
        else:
            metrics.update({"contact_iou": None, "contact_iou_reason": "no ground_truth/contacts.csv in the session",
                            "contact_iou_jaccard": None})
        metrics["robot_mode"] = mode
        metrics["max_table_penetration_m"] = r.max_table_penetration
        out[name] = metrics
        series[f"dynamics/{name}/p_WO"] = r.X_WO[:, :3, 3]
        series[f"dynamics/{name}/pos_err_m"] = dp
        series[f"dynamics/{name}/rot_err_deg"] = dr
        series[f"dynamics/{name}/contact"] = r.contact_active
    return out, series


# ----------------------------------------------------------------------------------------------- run
def run(inputs: EvaluationInputs, cfg: EvaluationConfig = EvaluationConfig(), *,
        progress: Callable[[float, str], None] | None = None, ground_truth: GroundTruth | None = None) -> EvaluationOutputs:
    """Evaluate tracking, geometry and dynamics of every method of one session (see module docstring).

    ``ground_truth`` overrides reading ``<session.root>/ground_truth`` (tests)."""
    _check_inputs(inputs)

    def report(f: float, msg: str) -> None:
        if progress:
            progress(float(f), msg)

    gt = ground_truth if ground_truth is not None else (
        load_ground_truth(inputs.session.root) if inputs.session.has_ground_truth else None)
    report(0.0, "tracking vs ground truth")
    tracking, series, X_OG0 = tracking_metrics(inputs, gt)
    if cfg.geometry:
        report(0.05, "geometry: alignment, chamfer, IoU")
        geometry, s2 = geometry_metrics(inputs.meshes, gt, X_OG0, cfg)
        series.update(s2)
    else:
        geometry = {m: {"chamfer_m": None, "iou": None, "reason": "geometry evaluation disabled"} for m in inputs.meshes}
    if gt is not None and gt.mesh is not None:
        X_show = X_OG0 if X_OG0 is not None else series.get("geometry/fused/X_OG")
        if X_show is not None:
            series["ground_truth/mesh_O/vertices"] = transform_points(X_show, np.asarray(gt.mesh.vertices, float))
            series["ground_truth/mesh_O/faces"] = np.asarray(gt.mesh.faces, np.int64)
    if cfg.dynamics:
        report(0.3, "dynamics: open-loop rollouts")
        dynamics, s3 = dynamics_metrics(inputs, gt, X_OG0, cfg,
                                        progress=lambda f, m: report(0.3 + 0.7 * f, m))
        series.update(s3)
    else:
        dynamics = {}
    report(1.0, "evaluation done")
    return EvaluationOutputs(tracking=tracking, geometry=geometry, dynamics=dynamics, series=series)
