"""Open-loop rollout of an object model on a table, pushed by a spherical end effector (pybullet).

Scene: the table is the half-space z ≤ ``table_height`` of W; the object is one rigid body built from
the model's convex collision pieces (Bullet convex hulls; the hull of the visual mesh if it has none), with mass m, centre of mass ``com_O`` and
rotational inertia ``I_O`` about it (principal axes: ``I_O = R diag(λ) Rᵀ``, the Bullet inertial
frame is ``X_OI = (R, com_O)``); the end effector is a sphere of radius ``ee_radius`` and mass ``m_E``,
gravity-compensated, driven by a force

    F = m_E [ω² (p_d − p) + 2ζω (ṗ_d − ṗ)]               (kinematic following, ω = follow_omega)
    F = K (p_d − p) − 2ζ√(K m_E) ṗ                         (impedance toward the command, K = stiffness)

clamped to ``max_ee_force``; it does not collide with the table and is held against spinning (very large
rotational inertia), like a sphere fixed to a flange. Friction and restitution pairs follow
Bullet's product rule: the object's own friction is ``table_friction_base`` = 1 and the table and sphere
carry μ_OT and μ_OR, so the pairs are exactly the model's ``friction.object_table`` / ``object_robot``;
table and sphere have restitution 1, so the object's own restitution is the pair's.
Effects (``service.sim.effects``) change gravity, restitution, damping, the robot clock, etc.

Determinism: each call owns a fresh ``pybullet.DIRECT`` client with fixed parameters and steps a fixed
``dt`` (semi-implicit, sequential-impulse solver), so the same inputs give the same output.
Reference for the protocol: method-notes §8.3 (Drake there; pybullet here, same scene contents).
"""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Mapping

import numpy as np

from service.mesh import Mesh
from service.model import ObjectModel
from service.sim.effects import EffectSpec, SimSettings, settings_for
from service.sim.types import RobotPath, RolloutResult, SimConfig
from service.transforms import X_inv, make_X, mat_to_quat, pose_from_xyzw, quat_from_xyzw, quat_to_mat, quat_to_xyzw


def principal_frame(inertia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric (3,3) inertia -> (eigenvalues (3,), rotation R (3,3), det +1) with I = R diag(λ) Rᵀ."""
    inertia = 0.5 * (np.asarray(inertia, float) + np.asarray(inertia, float).T)
    lam, R = np.linalg.eigh(inertia)
    if np.linalg.det(R) < 0:
        R[:, 2] = -R[:, 2]
    return lam, R


def with_collision(model: ObjectModel) -> ObjectModel:
    """The model itself, or, when it has no collision pieces, with the convex hull of its visual mesh."""
    if model.collision and not all(c.is_empty for c in model.collision):
        return model
    if model.visual is None or model.visual.is_empty or len(model.visual.vertices) < 4:
        raise ValueError("model has neither collision pieces nor a visual mesh")
    import trimesh

    hull = trimesh.Trimesh(np.asarray(model.visual.vertices, float), np.zeros((0, 3), np.int64), process=False).convex_hull
    return replace(model, collision=(Mesh.from_trimesh(hull),))


def _check(model: ObjectModel, X_WO0: np.ndarray, path: RobotPath, t_out: np.ndarray) -> None:
    if not np.isfinite(model.mass) or model.mass <= 0:
        raise ValueError(f"model mass must be positive, got {model.mass}")
    lam, _ = principal_frame(model.inertia_O)
    if np.any(lam <= 0) or lam.max() > lam.sum() - lam.max() + 1e-12 * lam.max():
        raise ValueError(f"model inertia is not physical (principal moments {lam})")
    if np.shape(X_WO0) != (4, 4):
        raise ValueError(f"X_WO0 must be (4,4), got {np.shape(X_WO0)}")
    if path.t.ndim != 1 or path.p_WE.shape != (len(path.t), 3) or len(path.t) < 2:
        raise ValueError(f"robot path must be t (M,) and p_WE (M,3) with M >= 2, got {path.t.shape}, {path.p_WE.shape}")
    if np.any(np.diff(path.t) <= 0):
        raise ValueError("robot path times must increase strictly")
    if t_out.ndim != 1 or len(t_out) < 1 or np.any(np.diff(t_out) < 0):
        raise ValueError("output times must be a non-decreasing (N,) array")


def rollout(
    model: ObjectModel,
    X_WO0: np.ndarray,
    v0: np.ndarray,
    w0: np.ndarray,
    robot_path: RobotPath | tuple[np.ndarray, np.ndarray],
    table_height: float,
    ee_radius: float,
    cfg: SimConfig = SimConfig(),
    *,
    t_out: np.ndarray | None = None,
    effects: Mapping[str, EffectSpec] | None = None,
) -> RolloutResult:
    """Simulate the object from ``X_WO0`` (4,4) with velocity ``v0`` (3,) of O's origin in W and
    angular velocity ``w0`` (3,) in O axes, while the sphere replays ``robot_path``.

    Output is sampled at ``t_out`` (N,) (default: the path times); the simulation starts at ``t_out[0]``.
    ``effects`` is the effect registry (default: ``service.sim.effects.EFFECTS``).
    """
    import pybullet as pb

    if not isinstance(robot_path, RobotPath):
        robot_path = RobotPath(np.asarray(robot_path[0], float), np.asarray(robot_path[1], float))
    t_out = np.asarray(robot_path.t if t_out is None else t_out, float)
    X_WO0 = np.asarray(X_WO0, float)
    model = with_collision(model)
    _check(model, X_WO0, robot_path, t_out)
    s: SimSettings = settings_for(model.effects, effects)

    dt = float(cfg.dt)
    t0 = float(t_out[0])
    n_steps = int(round((t_out[-1] - t0) / dt))
    frame_step = np.clip(np.round((t_out - t0) / dt).astype(int), 0, n_steps)

    # desired sphere path at every step (clock offset applied), and its velocity
    ts = t0 + dt * np.arange(n_steps + 1) + s.clock_offset
    p_d = np.stack([np.interp(ts, robot_path.t, robot_path.p_WE[:, i]) for i in range(3)], -1)
    if cfg.robot_mode == "impedance" and cfg.cmd_lowpass_tau > 0:
        a = dt / (cfg.cmd_lowpass_tau + dt)
        f = p_d.copy()
        for i in range(1, len(f)):
            f[i] = f[i - 1] + a * (p_d[i] - f[i - 1])
        p_d = f
    v_d = np.gradient(p_d, dt, axis=0) if len(p_d) > 1 else np.zeros_like(p_d)
    if cfg.robot_mode == "kinematic":
        kp = cfg.ee_mass * cfg.follow_omega**2
        kd = 2.0 * cfg.ee_mass * cfg.follow_omega
    elif cfg.robot_mode == "impedance":
        kp = cfg.impedance_stiffness
        kd = 2.0 * cfg.impedance_damping_ratio * np.sqrt(cfg.impedance_stiffness * cfg.ee_mass)
    else:
        raise ValueError(f"robot_mode must be 'kinematic' or 'impedance', got {cfg.robot_mode!r}")

    lam, R_OI = principal_frame(model.inertia_O)
    X_OI = make_X(R_OI, np.asarray(model.com_O, float))
    X_IO = X_inv(X_OI)

    cid = pb.connect(pb.DIRECT)
    try:
        kw = {"physicsClientId": cid}
        pb.setPhysicsEngineParameter(
            fixedTimeStep=dt, numSolverIterations=int(cfg.solver_iterations), numSubSteps=0,
            deterministicOverlappingPairs=1, restitutionVelocityThreshold=0.05, **kw,
        )
        pb.setGravity(*s.gravity_W, **kw)

        # table
        plane = pb.createCollisionShape(pb.GEOM_PLANE, **kw)
        table = pb.createMultiBody(0.0, plane, basePosition=[0, 0, float(table_height)], **kw)
        mu_ot = model.friction.object_table if s.friction_object_table is None else s.friction_object_table
        pb.changeDynamics(table, -1, lateralFriction=mu_ot * s.friction_scale_table,
                          restitution=1.0, **kw)

        # object
        with tempfile.TemporaryDirectory(prefix="vysics-sim-") as tmp:
            files = []
            for k, piece in enumerate(model.collision):
                if piece.is_empty:
                    continue
                f = Path(tmp) / f"piece_{k}.obj"
                Mesh(np.asarray(piece.vertices, float), np.asarray(piece.faces, np.int64)).save_obj(f)
                files.append(str(f))
            shape = pb.createCollisionShapeArray(
                shapeTypes=[pb.GEOM_MESH] * len(files), fileNames=files, meshScales=[[1, 1, 1]] * len(files), **kw
            )
        if shape < 0:
            raise ValueError("pybullet could not build the collision shape of the model")
        obj = pb.createMultiBody(
            baseMass=float(model.mass), baseCollisionShapeIndex=shape, basePosition=[0, 0, 0],
            baseInertialFramePosition=[float(x) for x in model.com_O],
            baseInertialFrameOrientation=quat_to_xyzw(mat_to_quat(R_OI)), **kw,
        )
        dyn = dict(lateralFriction=cfg.table_friction_base, restitution=float(s.restitution),
                   linearDamping=0.0, angularDamping=0.0,
                   spinningFriction=float(s.spinning_friction), rollingFriction=float(s.rolling_friction),
                   localInertiaDiagonal=[float(x) for x in lam], collisionMargin=float(cfg.collision_margin),
                   activationState=pb.ACTIVATION_STATE_DISABLE_SLEEPING)
        if s.contact_stiffness is not None:
            dyn["contactStiffness"] = float(s.contact_stiffness)
            dyn["contactDamping"] = float(s.contact_damping if s.contact_damping is not None
                                          else 2.0 * np.sqrt(s.contact_stiffness * model.mass))
        pb.changeDynamics(obj, -1, **dyn, **kw)

        # initial state, lifted out of the table if the start pose penetrates it
        lifted = 0.0
        if cfg.resolve_initial_penetration:
            verts = np.concatenate([np.asarray(c.vertices, float) for c in model.collision if not c.is_empty])
            zmin = (verts @ X_WO0[:3, :3].T + X_WO0[:3, 3])[:, 2].min()
            if zmin < table_height:
                lifted = float(table_height - zmin)
                X_WO0 = X_WO0.copy()
                X_WO0[2, 3] += lifted
        X_WI0 = X_WO0 @ X_OI
        pb.resetBasePositionAndOrientation(obj, X_WI0[:3, 3].tolist(), quat_to_xyzw(mat_to_quat(X_WI0[:3, :3])), **kw)
        R0 = X_WO0[:3, :3]
        w_W = R0 @ np.asarray(w0, float)
        v_com = np.asarray(v0, float) + np.cross(w_W, R0 @ np.asarray(model.com_O, float))
        pb.resetBaseVelocity(obj, v_com.tolist(), w_W.tolist(), **kw)

        # end effector
        sph = pb.createCollisionShape(pb.GEOM_SPHERE, radius=float(ee_radius), **kw)
        ee = pb.createMultiBody(float(cfg.ee_mass), sph, basePosition=p_d[0].tolist(), **kw)
        pb.resetBaseVelocity(ee, v_d[0].tolist(), [0, 0, 0], **kw)
        pb.changeDynamics(ee, -1, lateralFriction=model.friction.object_robot * s.friction_scale_robot,
                          restitution=1.0, linearDamping=0.0, angularDamping=0.0,
                          localInertiaDiagonal=[1e3, 1e3, 1e3], **kw)
        pb.setCollisionFilterPair(ee, table, -1, -1, 0, **kw)
        g_comp = -cfg.ee_mass * np.asarray(s.gravity_W, float)

        N = len(t_out)
        X_out = np.zeros((N, 4, 4))
        v_out = np.zeros((N, 3))
        w_out = np.zeros((N, 3))
        pE_out = np.zeros((N, 3))
        f_out = np.zeros(N)
        table_out = np.zeros(N, bool)
        max_pen = 0.0
        f_since = 0.0
        k = 0

        def sample(step: int) -> None:
            nonlocal k, f_since
            pos, orn = pb.getBasePositionAndOrientation(obj, **kw)
            lin, ang = pb.getBaseVelocity(obj, **kw)
            X_WI = pose_from_xyzw(pos, orn)
            X_WO = X_WI @ X_IO
            R = X_WO[:3, :3]
            w_Wk = np.asarray(ang)
            v_O = np.asarray(lin) - np.cross(w_Wk, R @ np.asarray(model.com_O, float))
            pe = pb.getBasePositionAndOrientation(ee, **kw)[0]
            on_table = len(pb.getContactPoints(obj, table, **kw)) > 0
            while k < N and frame_step[k] == step:
                X_out[k], v_out[k], w_out[k] = X_WO, v_O, R.T @ w_Wk
                pE_out[k], f_out[k], table_out[k] = pe, f_since, on_table
                k += 1
            f_since = 0.0

        # kinematic following feeds the path velocity forward; impedance damps the absolute velocity
        v_ff = v_d if cfg.robot_mode == "kinematic" else np.zeros_like(v_d)
        damped = s.linear_damping > 0 or s.angular_damping > 0
        sample(0)
        for i in range(1, n_steps + 1):
            pe, _ = pb.getBasePositionAndOrientation(ee, **kw)
            ve, _ = pb.getBaseVelocity(ee, **kw)
            F = kp * (p_d[i] - np.asarray(pe)) + kd * (v_ff[i] - np.asarray(ve)) + g_comp
            nF = np.linalg.norm(F)
            if nF > cfg.max_ee_force:
                F = F * (cfg.max_ee_force / nF)
            pb.applyExternalForce(ee, -1, F.tolist(), list(pe), pb.WORLD_FRAME, **kw)
            if damped:
                pc, qc = pb.getBasePositionAndOrientation(obj, **kw)
                vc, wc = pb.getBaseVelocity(obj, **kw)
                R_WI = quat_to_mat(quat_from_xyzw(qc))
                f_d = -model.mass * s.linear_damping * np.asarray(vc)
                tau_d = -s.angular_damping * (R_WI @ (lam * (R_WI.T @ np.asarray(wc))))
                pb.applyExternalForce(obj, -1, f_d.tolist(), list(pc), pb.WORLD_FRAME, **kw)
                pb.applyExternalTorque(obj, -1, tau_d.tolist(), pb.WORLD_FRAME, **kw)
            pb.stepSimulation(**kw)
            fr = sum(c[9] for c in pb.getContactPoints(obj, ee, **kw))
            f_since = max(f_since, fr)
            for c in pb.getContactPoints(obj, table, **kw):
                max_pen = max(max_pen, -c[8])
            if k < N and frame_step[k] == i:
                sample(i)
        while k < N:  # only when t_out has a single sample
            sample(frame_step[k])
    finally:
        pb.disconnect(cid)

    return RolloutResult(
        t=t_out, X_WO=X_out, v_WO_W=v_out, w_WO_O=w_out, p_WE=pE_out,
        contact_active=f_out > cfg.contact_force_threshold, robot_force=f_out, table_contact=table_out,
        max_table_penetration=float(max_pen), lifted_at_start=lifted,
    )
