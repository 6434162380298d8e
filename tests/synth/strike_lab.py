"""An isolated strike in the synthetic lab's own world (``service.synth.sim``'s engine settings, table, object and
end-effector sphere, the strike's impedance law and command profile): the launch of a resting baking box struck
through its CoM (or lower) by the 10 kg sphere, for the lab-strike test and ``benchmarks/strike_restitution.py lab``.

The physics of a heavy striker: the box leaves at (1 + e) m_E / (m_E + m) times the sphere's approach speed when struck
through its CoM on a frictionless table (10 kg on 0.3 kg: 0.971 (1 + e)).
"""

from __future__ import annotations

import tempfile

import numpy as np
import pybullet as pb

from service.sim.touch import TouchSplitter
from service.synth import sim
from service.synth.objects import make_object
from service.transforms import make_X

H_LAB = 1.0 / 240.0  # s, the lab's physics step


def lab_strike(v: float, e: float, phase: float, *, mu: float = 0.0, height: float | None = None,
               run_up: float = sim.STRIKE_RUN_UP, breaking: float | None = None,
               touches: list | None = None, substeps: int = 1) -> tuple[float, float]:
    """(approach, launch) in m/s: the sphere's speed in the step before the box first moves, and the box's largest
    CoM speed along the strike over the next 6 steps (its launch; on a frictionless table the speed it keeps).

    ``v``: the command's speed at the surface (m/s; the sphere lags and hits at about 0.8 v, as in the lab); ``e``: the
    object's restitution; ``phase`` in [0, 1): where within a physics step the touch falls (the run-up is lengthened by
    ``phase`` x one step's travel); ``mu``: table friction; ``height``: contact height above the table (m; default the
    CoM's); ``breaking``: Bullet's contact breaking threshold for the whole world (a factor of each shape's bounding
    radius; None = Bullet's 0.02, the lab's). The sphere's settings are the lab's for ``interaction="strike"``
    (``sim.STRIKE_CONTACT_PROCESSING_M``, ``sim.STRIKE_TOUCH_SPLIT``: with the step split at the time of impact,
    ``touches`` (a list, when given) receives each split's (time into the step s, overlap m the contact starts with,
    the sphere's speed at the touch m/s)). ``substeps``: physics steps per lab step (1: the lab's 240 Hz; more: a
    reference nearer the continuous physics, the launch still read over 6 lab steps)."""
    obj = make_object("baking_box")
    h = H_LAB / substeps
    cid = pb.connect(pb.DIRECT)
    tmp = tempfile.TemporaryDirectory(prefix="vysics-strike-")
    try:
        sim.configure_world(cid, h, np.array([0.0, 0.0, -sim.GRAVITY]))
        if breaking is not None:
            pb.setPhysicsEngineParameter(contactBreakingThreshold=breaking, physicsClientId=cid)
        table = sim.add_table(cid, 0.0, mu, 0.0)
        zmin = float(np.asarray(obj.mesh.vertices)[:, 2].min())
        X_WM0 = make_X(np.eye(3), np.array([0.0, 0.0, -zmin + 0.0002]))
        body, _, _, _ = sim.add_object(cid, obj, X_WM0, np.zeros(3), e, tmp.name)
        park = np.array([0.0, 0.0, 0.6])
        sphere = sim.add_sphere(cid, "strike", park, 0.15, table)
        m_e, k_e, d_e = sim.controller("strike")
        g = np.array([0.0, 0.0, -sim.GRAVITY])

        def step(cmd: np.ndarray) -> None:
            sim.drive_sphere(cid, sphere, cmd, m_e, k_e, d_e, g)
            pb.stepSimulation(physicsClientId=cid)

        for _ in range(int(0.5 / h)):  # settle
            step(park)
        c = np.asarray(pb.getBasePositionAndOrientation(body, physicsClientId=cid)[0])
        half_x = 0.5 * float(np.ptp(np.asarray(obj.mesh.vertices)[:, 0]))
        z = c[2] if height is None else height
        run = run_up + phase * 0.8 * v * H_LAB
        start = np.array([c[0] - half_x - sim.EE_RADIUS - run, 0.0, z])
        # the lab's strike command (``_Planner._plan_strike``): constant acceleration to v at 0.6 of the sphere's lag
        # beyond the surface, then a brake to rest over STRIKE_BRAKE
        L = run + 0.6 * 2.0 * np.sqrt(m_e / k_e) * v
        t1, t2 = 2.0 * L / v, 2.0 * sim.STRIKE_BRAKE / v

        def cmd(t: float) -> np.ndarray:
            if t < t1:
                return start + np.array([L * (t / t1) ** 2, 0.0, 0.0])
            tau = min((t - t1) / t2, 1.0)
            return start + np.array([L + sim.STRIKE_BRAKE * (1.0 - (1.0 - tau) ** 2), 0.0, 0.0])

        pb.resetBasePositionAndOrientation(sphere, start.tolist(), [0, 0, 0, 1], physicsClientId=cid)
        pb.resetBaseVelocity(sphere, [0, 0, 0], [0, 0, 0], physicsClientId=cid)
        for _ in range(int(0.1 / h)):
            step(start)
        vs, vb = [], []
        def touched(tt: float) -> None:
            if touches is not None:
                cps = pb.getClosestPoints(sphere, body, 0.01, physicsClientId=cid)
                v_touch = pb.getBaseVelocity(sphere, physicsClientId=cid)[0][0]
                touches.append((tt, -min((c[8] for c in cps), default=np.inf), v_touch))

        drive = lambda c: sim.drive_sphere(cid, sphere, c, m_e, k_e, d_e, g)  # noqa: E731
        splitter = TouchSplitter(cid, sphere, body)
        for k in range(int((t1 + 0.1) / h)):
            if sim.STRIKE_TOUCH_SPLIT:  # the step split at the time of impact (the lab's strike_step)
                sim.strike_step(splitter, h, lambda s: cmd(k * h + s), m_e, k_e, d_e, drive, touched)
            else:
                step(cmd(k * h))
            vs.append(pb.getBaseVelocity(sphere, physicsClientId=cid)[0][0])
            vb.append(pb.getBaseVelocity(body, physicsClientId=cid)[0][0])
        vs, vb = np.asarray(vs), np.asarray(vb)
        k0 = int(np.argmax(vb > 0.02))
        if vb[k0] <= 0.02 or k0 == 0:
            raise RuntimeError("the sphere did not strike the box")
        return float(vs[k0 - 1]), float(vb[k0:k0 + 6 * substeps].max())
    finally:
        pb.disconnect(physicsClientId=cid)
        tmp.cleanup()
