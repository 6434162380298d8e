"""Open-loop rollouts of an ObjectModel in pybullet, with the effect parameters of the residual loop.

The object is a rigid body (mass m, CoM c_O, inertia I about c, principal axes) with the model's
convex collision geometry, on the half-space ``z = table_height + table_offset``; the robot, when
there is one, is a sphere of radius r dragged along its recorded path by a stiff fixed constraint whose
target leads the path by the constraint's steady lag (``CONSTRAINT_LEAD_STEPS``), so the sphere is on its
path in free motion.
Integration is pybullet's semi-implicit Euler at a sub-step ``h = dt / ceil(dt / sim_substep_s)``.

Pose bookkeeping: pybullet's base frame is the inertial frame I (origin at the CoM, axes the
principal axes), so ``X_WI = X_WO X_OI`` with ``X_OI = (R_OI, c_O)``, and the start velocity of the
CoM is ``v_WI = v_WO + ω_W × (R_WO c_O)``. The start velocity is the backward-difference velocity of
the data (``p[k] = p[k-1] + dt v[k]``), which is what semi-implicit Euler expects.

Effect keys read here (all optional; absent = the nominal model, see ``service.residuals.effects``).
Names and meanings are those of ``service.sim.effects`` where both exist, so an ``ObjectModel.effects``
means the same in both simulators:
``restitution`` (object; table and sphere have 1, Bullet multiplies), ``linear_damping`` and
``angular_damping`` (viscous rates b, 1/s: force −m b v at the CoM and torque −b I ω, applied before
every sub-step with Bullet's own damping off — Bullet's multibody damping is −m d (1 + |v|) v, not
viscous; the same choice as ``service.export.urdf``'s ``apply_damping`` and the synthetic lab),
``table_tilt_x`` / ``table_tilt_y`` (rad; g = R_y(ty) R_x(tx) g), ``clock_offset`` (s, robot path read
at t + δ), ``friction_object_table`` (replaces μ_OT), ``friction_scale_robot`` (multiplies μ_OR), and
three keys of the recording rather than of the object: ``gravity_scale`` (|g| = 9.81 s),
``time_scale`` (physical seconds per data second) and ``table_offset`` (m, added to the table height).

This simulator exists beside ``service.sim.rollout`` because the residual loop needs thousands of
short rollouts: it steps Bullet without per-step Python work (poses are read once per output frame
and converted in one batch). ``service_sim_simulator`` wraps ``service.sim.rollout`` in the same
``SimRequest -> X_WO`` interface, for cross-checks and for callers that want one physics everywhere.
"""

from __future__ import annotations

import numpy as np

from service.model import ObjectModel
from service.residuals.types import SPHERE_DRIVES, SimRequest
from service.transforms import make_X, mat_to_quat, quat_from_xyzw, quat_to_mat, quat_to_xyzw, so3_exp

G = 9.81
# The sphere's fixed constraint closes the fraction erp of its position error per sub-step, so at a steady
# velocity it trails its target by (1 − erp) / erp sub-steps (measured: 3.92 mm at 0.5 m/s with 1.96 ms steps,
# 8 ms). The target is read that much ahead: the sphere is on its recorded path in free motion (strikes hit on
# time), and it still yields like before in sustained contact. (erp = 1 also removes the lag, but makes the
# sphere press into a pushed object: a hidden clock offset of 0.1 s on a lab push was then fitted 0.043 s.)
CONSTRAINT_ERP = 0.2
CONSTRAINT_LEAD_STEPS = (1.0 - CONSTRAINT_ERP) / CONSTRAINT_ERP
# How the constraint's target is set from the recorded path (``BulletSimulator(sphere_drive=...)``): "lead" reads the
# path (1 − erp) / erp sub-steps ahead (exact at a steady velocity only: at the brake of a strike the sphere rounds
# the corner of its speed and hands the object a launch 1.5-2.5 % too slow); "inverse" inverts the constraint's
# update (``sphere_targets``: the sphere lands on its path at every sub-step in free motion, whatever its velocity
# does, and a contact still pushes it off as softly as before).
FAR_ABOVE_M = 50.0  # where the robot sphere is parked for tosses without a robot (service.sim needs one)
# Bullet's contact breaking threshold (gContactBreakingThreshold, a process-wide global, 0.02 m by default): pairs closer
# than this get contact points before they touch. Measured (docs/residuals.md §6): when the point exists for many
# sub-steps before a strike touches, the strike's bounce is lost — with 0.02 m and 2 ms sub-steps in 5-7 of 12 contact
# phases (e = 0.3, 0.35-0.6 m/s; at 1 ms in all), with 1-2 mm in none. ``contact_breaking_m`` sets it for the rollouts
# of one simulator and puts this default back after each rollout (other Bullet users in the process share the global).
BULLET_CONTACT_BREAKING_M = 0.02


def sphere_targets(path: np.ndarray, erp: float = CONSTRAINT_ERP) -> np.ndarray:
    """(J,3) constraint targets u_j that put a freely moving sphere on its path p_j (J,3, m, frame W, one row per
    sub-step, p_0 the start) at every sub-step.

    The fixed constraint closes the fraction erp of its error per sub-step, x_j = x_{j−1} + erp (u_j − x_{j−1}), so
    u_j = p_{j−1} + (p_j − p_{j−1}) / erp gives x_j = p_j whenever x_{j−1} = p_{j−1} (exact for any path, where reading
    the path (1 − erp) / erp sub-steps ahead is exact at a constant velocity only). A contact that pushes the sphere
    off its path is still corrected by the fraction erp per sub-step: x_j − p_j = (1 − erp)(x_{j−1} − p_{j−1}).
    """
    p = np.asarray(path, float)
    u = p.copy()
    u[1:] = p[:-1] + (p[1:] - p[:-1]) / erp
    return u


def gravity_vector(effects: dict[str, float]) -> np.ndarray:
    """World gravity (3,) implied by the gravity effects (scale, then tilt about x, then y)."""
    g = np.array([0.0, 0.0, -G * float(effects.get("gravity_scale", 1.0))])
    g = so3_exp(np.array([float(effects.get("table_tilt_x", 0.0)), 0.0, 0.0])) @ g
    g = so3_exp(np.array([0.0, float(effects.get("table_tilt_y", 0.0)), 0.0])) @ g
    return g


def _principal(model: ObjectModel) -> tuple[np.ndarray, np.ndarray]:
    """Principal moments (3,) and rotation R_OI (3,3) (right-handed) of the model's inertia."""
    I = 0.5 * (np.asarray(model.inertia_O, float) + np.asarray(model.inertia_O, float).T)
    w, V = np.linalg.eigh(I)
    if np.linalg.det(V) < 0:
        V[:, 2] = -V[:, 2]
    return np.maximum(w, 1e-9), V


def _frictions(model: ObjectModel, eff: dict[str, float]) -> tuple[float, float]:
    mu_t = float(eff.get("friction_object_table", model.friction.object_table))
    mu_r = float(model.friction.object_robot) * float(eff.get("friction_scale_robot", 1.0))
    return mu_t, mu_r


class BulletSimulator:
    """Callable ``SimRequest -> (T,4,4)`` rollouts; owns one pybullet DIRECT client (call ``close``)."""

    def __init__(self, sim_substep_s: float = 0.002, collision_margin: float = 0.0, contact_breaking_m: float | None = None,
                 sphere_drive: str = "lead", contact_persist_m: float | None = None, touch_split: bool = False,
                 restitution_threshold_mps: float = 0.05):
        import pybullet

        if contact_breaking_m is not None and not contact_breaking_m > 0:
            raise ValueError(f"contact_breaking_m must be > 0 m or None, not {contact_breaking_m!r}")
        if contact_persist_m is not None and not contact_persist_m > 0:
            raise ValueError(f"contact_persist_m must be > 0 m or None, not {contact_persist_m!r}")
        if sphere_drive not in SPHERE_DRIVES:
            raise ValueError(f"sphere_drive must be one of {SPHERE_DRIVES}, not {sphere_drive!r}")
        if not 0.0 <= restitution_threshold_mps < np.inf:
            raise ValueError(f"restitution_threshold_mps must be >= 0 m/s, not {restitution_threshold_mps!r}")
        # relative normal speed below which a contact gets no bounce, m/s (Bullet's restitutionVelocityThreshold)
        self.restitution_threshold = float(restitution_threshold_mps)
        self._p = pybullet
        self._cid = pybullet.connect(pybullet.DIRECT)
        self.substep = float(sim_substep_s)
        self.margin = float(collision_margin)
        self.contact_breaking = None if contact_breaking_m is None else float(contact_breaking_m)
        # the object-table manifold re-made with this threshold at the object's first touch (None: off). Bullet drops a
        # manifold point once its witness points have moved apart along the surface by more than the threshold, so at
        # 1 mm a body sliding at v h > 0.5 mm per sub-step holds about one point and sinks (docs/residuals-findings.md,
        # "Resting contact at the contact breaking threshold"); the first touch is still made at contact_breaking_m
        self.contact_persist = None if contact_persist_m is None else float(contact_persist_m)
        self.sphere_drive = sphere_drive
        # a sub-step split at the time of impact of the robot sphere on the object (``service.sim.touch``; False: off):
        # the sphere's contact starts at the touch instead of up to v h inside, so Bullet's push-out adds nothing to a
        # strike's launch, while a sustained contact keeps Bullet's law (docs/residuals-findings.md, "A strike's contact
        # that starts at the touch")
        self.touch_split = bool(touch_split)
        self._hulls: dict = {}

    def _hull_vertices(self, model: ObjectModel) -> np.ndarray:
        """(H,3) convex-hull vertices of the collision pieces (visual mesh if none), cached per geometry."""
        verts = [np.asarray(piece.vertices, float) for piece in model.collision if len(piece.vertices)]
        V = np.concatenate(verts, 0) if verts else np.asarray(model.visual.vertices, float)
        key = (V.shape, hash(V.tobytes()))
        if key not in self._hulls:
            if len(V) > 16:
                from scipy.spatial import ConvexHull

                V = V[ConvexHull(V).vertices]
            self._hulls = {key: V}  # one geometry at a time is all the loop uses
        return self._hulls[key]

    def _damp(self, body: int, mass: float, moments: np.ndarray, b_lin: float, b_ang: float) -> None:
        p, cid = self._p, self._cid
        v, w = p.getBaseVelocity(body, physicsClientId=cid)
        pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=cid)
        if b_lin:
            p.applyExternalForce(body, -1, [-mass * b_lin * x for x in v], pos, p.WORLD_FRAME, physicsClientId=cid)
        if b_ang:
            R = quat_to_mat(np.array([orn[3], orn[0], orn[1], orn[2]]))
            tau = -b_ang * (R @ (moments * (R.T @ np.asarray(w))))
            p.applyExternalTorque(body, -1, tau.tolist(), p.WORLD_FRAME, physicsClientId=cid)

    def _split_substep(self, splitter, cons: int, target: np.ndarray, h: float, body: int, mass: float,
                       moments: np.ndarray, b_lin: float, b_ang: float) -> float:
        """One sub-step of ``h`` s towards the constraint target ``target`` (3,) m, W, split at the sphere's time of
        impact on the object (``service.sim.touch.TouchSplitter``). The constraint moves the sphere at w = erp (u − x) / h
        over the whole sub-step (x its position at the start): in a part of τ s starting t s in, the world's erp is
        erp τ / h and the target u + w t, so the sphere is where the unsplit sub-step puts it, on its path; the force
        bound is scaled by h / τ (the same impulse per part). Damping forces are applied per part. Returns the split
        time (s; 0.0 when not split)."""
        p, cid = self._p, self._cid
        x0 = np.asarray(p.getBasePositionAndOrientation(splitter.sphere, physicsClientId=cid)[0], float)
        u = np.asarray(target, float)
        w = CONSTRAINT_ERP * (u - x0) / h

        def apply(t: float, part: float) -> None:
            p.changeConstraint(cons, (u + w * t).tolist(), maxForce=5000.0 * h / part, physicsClientId=cid)
            if b_lin or b_ang:
                self._damp(body, mass, moments, b_lin, b_ang)

        return splitter.step(h, lambda t: (w, np.zeros(3)), apply)

    def _remake_manifold(self, body: int, table: int, threshold: float) -> None:
        """Re-make the object-table contact manifold with ``threshold`` (m); every other pair keeps its own. Bullet
        fixes a manifold's threshold when the manifold is made, so the pair is filtered off (its manifold freed),
        then on again while the global is ``threshold``, and the global is put back."""
        p, cid = self._p, self._cid
        p.setCollisionFilterPair(body, table, -1, -1, 0, physicsClientId=cid)
        p.performCollisionDetection(physicsClientId=cid)
        p.setPhysicsEngineParameter(contactBreakingThreshold=threshold, physicsClientId=cid)
        p.setCollisionFilterPair(body, table, -1, -1, 1, physicsClientId=cid)
        p.performCollisionDetection(physicsClientId=cid)
        p.setPhysicsEngineParameter(contactBreakingThreshold=self.contact_breaking, physicsClientId=cid)

    def close(self) -> None:
        if getattr(self, "_cid", None) is not None:
            try:
                self._p.disconnect(physicsClientId=self._cid)
            except Exception:  # already gone
                pass
            self._cid = None

    def __enter__(self) -> "BulletSimulator":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):
        self.close()

    def __call__(self, req: SimRequest) -> np.ndarray:
        """(T,4,4) X_WO of the rollout at the request's times (W, m)."""
        if self._cid is None:
            raise RuntimeError("simulator is closed")
        if self.contact_breaking is None:
            return self._rollout(req)
        p = self._p
        p.setPhysicsEngineParameter(contactBreakingThreshold=self.contact_breaking, physicsClientId=self._cid)
        try:
            return self._rollout(req)
        finally:  # a process-wide global in Bullet: leave it as other users expect it
            p.setPhysicsEngineParameter(contactBreakingThreshold=BULLET_CONTACT_BREAKING_M, physicsClientId=self._cid)

    def _rollout(self, req: SimRequest) -> np.ndarray:
        p, cid = self._p, self._cid
        eff = {**req.model.effects, **req.effects}
        model = req.model
        t = np.asarray(req.t, float)
        T = len(t)
        out = np.zeros((T, 4, 4))
        out[0] = req.X_WO0
        if T == 1:
            return out
        s_time = float(eff.get("time_scale", 1.0))
        dts = np.diff(t) * s_time  # physical durations of the frame intervals
        n_sub = np.maximum(1, np.ceil(dts / self.substep - 1e-9)).astype(int)
        h = float(np.median(dts / n_sub))

        p.resetSimulation(physicsClientId=cid)
        p.setGravity(*gravity_vector(eff), physicsClientId=cid)
        p.setPhysicsEngineParameter(
            fixedTimeStep=h, numSolverIterations=50, numSubSteps=0, deterministicOverlappingPairs=1,
            restitutionVelocityThreshold=self.restitution_threshold, erp=CONSTRAINT_ERP, physicsClientId=cid,
        )
        mu_t, mu_r = _frictions(model, eff)
        table_z = float(req.table_height) + float(eff.get("table_offset", 0.0))
        plane = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=cid)
        table = p.createMultiBody(0, plane, basePosition=[0, 0, table_z], physicsClientId=cid)
        p.changeDynamics(table, -1, lateralFriction=mu_t, restitution=1.0, physicsClientId=cid)

        moments, R_OI = _principal(model)
        com = np.asarray(model.com_O, float)
        V_O = self._hull_vertices(model)
        V_I = (V_O - com) @ R_OI  # p_I = R_OIᵀ (p_O − c); one convex hull of all pieces
        shape = p.createCollisionShape(p.GEOM_MESH, vertices=V_I.tolist(), physicsClientId=cid)
        X_OI = make_X(R_OI, com)
        X_WI0 = req.X_WO0 @ X_OI
        q = mat_to_quat(X_WI0[:3, :3])
        body = p.createMultiBody(
            float(model.mass), shape, basePosition=X_WI0[:3, 3].tolist(), baseOrientation=quat_to_xyzw(q),
            physicsClientId=cid,
        )
        p.changeDynamics(
            body, -1, localInertiaDiagonal=moments.tolist(), lateralFriction=1.0,
            restitution=float(eff.get("restitution", 0.0)),
            linearDamping=0.0, angularDamping=0.0,
            collisionMargin=self.margin, activationState=p.ACTIVATION_STATE_DISABLE_SLEEPING, physicsClientId=cid,
        )
        R0 = req.X_WO0[:3, :3]
        w_W = R0 @ (np.asarray(req.w0_WO_O, float) / s_time)
        v_WI = np.asarray(req.v0_WO_W, float) / s_time + np.cross(w_W, R0 @ com)
        p.resetBaseVelocity(body, v_WI.tolist(), w_W.tolist(), physicsClientId=cid)

        ee_path = None
        if req.robot is not None:
            rb = req.robot
            rt = np.asarray(rb.t, float)
            rp = np.asarray(rb.p_WE, float)
            # sphere targets at every sub-step, on the data clock shifted by the clock offset
            tt = np.concatenate([t[k] + (t[k + 1] - t[k]) * (np.arange(1, n_sub[k] + 1) / n_sub[k]) for k in range(T - 1)])
            tt = np.concatenate([[t[0]], tt]) + float(eff.get("clock_offset", 0.0))
            if self.sphere_drive == "lead":
                # + the constraint's steady lag (1 − erp) / erp sub-steps: the sphere is on its path in free motion
                tt = tt + CONSTRAINT_LEAD_STEPS * h
            ee_path = np.stack([np.interp(tt, rt, rp[:, i]) for i in range(3)], 1)
            if self.sphere_drive == "inverse":
                ee_path = sphere_targets(ee_path)
            sshape = p.createCollisionShape(p.GEOM_SPHERE, radius=float(rb.radius), physicsClientId=cid)
            sphere = p.createMultiBody(10.0, sshape, basePosition=ee_path[0].tolist(), physicsClientId=cid)
            p.changeDynamics(sphere, -1, lateralFriction=mu_r, restitution=1.0, linearDamping=0.0,
                             angularDamping=0.0, physicsClientId=cid)
            p.setCollisionFilterPair(sphere, table, -1, -1, 0, physicsClientId=cid)
            cons = p.createConstraint(sphere, -1, -1, -1, p.JOINT_FIXED, [0, 0, 0], [0, 0, 0],
                                      ee_path[0].tolist(), physicsClientId=cid)

        splitter = None
        if ee_path is not None and self.touch_split:
            from service.sim.touch import BULLET_ERPS, TouchSplitter

            erps = {**BULLET_ERPS, "erp": CONSTRAINT_ERP}
            # a point made while the gap is open is not solved (the lab's strike sphere has the same setting)
            p.changeDynamics(sphere, -1, contactProcessingThreshold=0.0, physicsClientId=cid)
            splitter = TouchSplitter(cid, sphere, body, erps)
        persist = self.contact_persist if self.contact_breaking is not None else None
        b_lin = float(eff.get("linear_damping", 0.0)) / s_time
        b_ang = float(eff.get("angular_damping", 0.0)) / s_time
        mass = float(model.mass)
        pos = np.zeros((T - 1, 3))
        quat = np.zeros((T - 1, 4))
        j = 0
        for k in range(T - 1):
            for _ in range(int(n_sub[k])):
                j += 1
                if splitter is not None:  # split at the sphere's time of impact when it falls in this sub-step
                    self._split_substep(splitter, cons, ee_path[j], h, body, mass, moments, b_lin, b_ang)
                else:
                    if ee_path is not None:
                        p.changeConstraint(cons, ee_path[j].tolist(), maxForce=5000.0, physicsClientId=cid)
                    if b_lin or b_ang:  # viscous: F = −m b v at the CoM, τ = −b I_W ω
                        self._damp(body, mass, moments, b_lin, b_ang)
                    p.stepSimulation(physicsClientId=cid)
                if persist is not None and p.getContactPoints(bodyA=body, bodyB=table, physicsClientId=cid):
                    self._remake_manifold(body, table, persist)
                    persist = None
            ps, orn = p.getBasePositionAndOrientation(body, physicsClientId=cid)
            pos[k] = ps
            quat[k] = quat_from_xyzw(orn)
        X_WI = make_X(quat_to_mat(quat), pos)
        R_IO = R_OI.T
        out[1:, :3, :3] = X_WI[:, :3, :3] @ R_IO
        out[1:, :3, 3] = pos - out[1:, :3, :3] @ com
        out[1:, 3, 3] = 1.0
        return out


def make_simulator(sim_substep_s: float = 0.002, contact_breaking_m: float | None = None, sphere_drive: str = "lead",
                   contact_persist_m: float | None = None, touch_split: bool = False,
                   restitution_threshold_mps: float = 0.05) -> BulletSimulator:
    """The built-in simulator used when the caller injects none (``ResidualConfig.sim_substep_s``,
    ``contact_breaking_m``, ``sphere_drive``, ``contact_persist_m``, ``touch_split`` and
    ``restitution_threshold_mps``)."""
    return BulletSimulator(sim_substep_s, contact_breaking_m=contact_breaking_m, sphere_drive=sphere_drive,
                           contact_persist_m=contact_persist_m, touch_split=touch_split,
                           restitution_threshold_mps=restitution_threshold_mps)


def simulator_for(cfg) -> BulletSimulator:
    """The loop's built-in simulator for the settings ``cfg`` (a ``ResidualConfig``): its sub-step, contact breaking
    threshold, sphere drive, contact persistence, the sub-step split at the touch and the restitution velocity
    threshold. ``run`` uses it when the caller injects no simulator;
    diagnosis scripts replay with it so that their rollouts are the loop's."""
    return make_simulator(cfg.sim_substep_s, cfg.contact_breaking_m, cfg.sphere_drive, cfg.contact_persist_m,
                          cfg.touch_split, cfg.restitution_threshold_mps)


def service_sim_simulator(sim_cfg=None):
    """``SimRequest -> X_WO`` through ``service.sim.rollout`` (one fresh Bullet world per call).

    Keys that ``service.sim`` lacks are handled here: ``gravity_scale`` through an extended effect
    registry, ``table_offset`` by moving the table, ``time_scale`` by scaling times and start velocities;
    tosses park the sphere far above the table.
    """
    from dataclasses import replace

    from service.sim import EFFECTS, EffectSpec, RobotPath as SimPath, SimConfig, rollout

    registry = dict(EFFECTS)
    if "gravity_scale" not in registry:
        registry["gravity_scale"] = EffectSpec(
            lambda s, v: replace(s, gravity_W=tuple(float(x) * float(v) for x in s.gravity_W)),
            "gravity magnitude factor", 1.0, (0.5, 1.5),
        )
    own = {"table_offset", "time_scale"} - set(registry)
    cfg = sim_cfg if sim_cfg is not None else SimConfig.fast()

    def simulate(req: SimRequest) -> np.ndarray:
        eff = {**req.model.effects, **req.effects}
        st = float(eff.get("time_scale", 1.0)) if "time_scale" in own else 1.0
        dz = float(eff.get("table_offset", 0.0)) if "table_offset" in own else 0.0
        sim_eff = {k: v for k, v in eff.items() if k not in own}
        model = replace(req.model, effects=sim_eff)
        t = np.asarray(req.t, float)
        t_phys = t[0] + st * (t - t[0])
        if req.robot is not None:
            rt = np.asarray(req.robot.t, float)
            path = SimPath(t[0] + st * (rt - t[0]), np.asarray(req.robot.p_WE, float))
            radius = float(req.robot.radius)
        else:
            far = np.array([0.0, 0.0, req.table_height + FAR_ABOVE_M])
            path = SimPath(np.array([t_phys[0] - 1.0, t_phys[-1] + 1.0]), np.stack([far, far]))
            radius = 0.01
        r = rollout(model, req.X_WO0, np.asarray(req.v0_WO_W, float) / st, np.asarray(req.w0_WO_O, float) / st,
                    path, req.table_height + dz, radius, cfg, t_out=t_phys, effects=registry)
        return r.X_WO

    return simulate
