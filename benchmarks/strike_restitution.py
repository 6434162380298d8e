"""Diagnosis of restitution on strike sessions (docs/residuals.md §6, docs/residuals-findings.md "Restitution on strikes"). Reads ground truth:
for diagnosis only, never part of the service.

    python benchmarks/strike_restitution.py phases [--speeds 0.35 0.45 0.6] [--phases 12]
    python benchmarks/strike_restitution.py blocks --seeds 666 667 [--pose-noise 0] [--contact-breaking off 0.001]
        [--lab-strike-contact touch|velocity|split|bullet] [--touch-split]
    python benchmarks/strike_restitution.py lab [--speeds 0.4 0.55 0.7] [--phases 12] [--restitutions 0.1 0.3 0.5]
        [--sphere-contact bullet touch velocity split] [--breaking off 0.005 0.002 0.001] [--mu 0] [--height-frac F]
        [--reference 16]
    python benchmarks/strike_restitution.py lab-rest

``phases``: a 10 kg sphere strikes a resting 0.3 kg box (9.5 x 6.5 x 12.5 cm) through its CoM on a frictionless table;
the box's launch speed with e = 0.3 over the one with e = 0 (the physics: 1.3 for a heavy striker) over contact
phases (start gaps uniform over 5 mm, so the touch falls anywhere within a sub-step). Rows: the loop's simulator
(``BulletSimulator``: sphere dragged along its path, 2 ms sub-steps) with Bullet's contact breaking threshold, with
1 mm, and with 1 mm and the sub-step split at the touch (the e = 0 launch over v is printed too: the push-out of a
contact that starts inside the object; the rows with a contact erp of 0.05 in docs/residuals-findings.md, command P,
were made with the loop's ``contact_erp``, since removed), and a world with the synthetic lab's settings (240 Hz steps, Bullet's default restitution threshold 0.2 m/s and
contact breaking 0.02 m, a free sphere moving at the strike speed).

``lab``: the same strike in the synthetic lab's own world (``tests/synth/strike_lab.py``: ``service.synth.sim``'s engine
settings, table, object, sphere, impedance law and strike command; 240 Hz): the launch / approach speed with e = 0 and
the launch with e over the one with e = 0 per contact phase, with the sphere-object contact solved from the touch on
(``touch``: ``sim.STRIKE_TOUCH_PROCESSING_M``; off in the lab), from the touch on at the velocity level only
(``velocity``: also ``sim.STRIKE_VELOCITY_ONLY``, no push-out of the overlap the contact starts with; off in the lab,
docs/residuals-findings.md "The launch kick") or as Bullet makes it (``bullet``: every contact point solved, the lab's default),
each with Bullet's contact breaking threshold for the whole world as given
(``--breaking``: a factor of each shape's bounding radius; ``off`` = Bullet's 0.02, the lab's). ``--height-frac`` strikes at that fraction of the box's height (the lab: 0.3) instead
of through the CoM.

``lab-rest``: the lab's baking box (μ 0.15) at rest for 2 s after the lab's settling, after a release tilted 5 mrad
and after a release 0.3 rad onto an edge (it rocks onto its face), then launched at 0.5 m/s (deceleration against
μ g), with lab-wide settings varied: Bullet's contact breaking threshold (a factor of each shape's bounding radius,
0.02 by default) and the hull margin. The lab's strike setting acts on the sphere-object pair only and leaves these
rows as Bullet's default gives them.

``blocks``: a synthetic-lab strike session with a hidden restitution 0.3 (the settings of ``benchmarks/residuals.py
strike``); on the loop's blocks where restitution acts, the block error (position + rho * angle on the effect's frames)
with e = 0 and with the true e, per contact breaking setting, and the e in a grid that fits each block best.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

E_TRUE = 0.3
BOX_HALF = (0.0475, 0.0325, 0.0625)


def _lab_like_launch(v: float, e: float, start_gap: float) -> float:
    """Launch speed / v of the box struck by a free 10 kg sphere at v, with the synthetic lab's step and thresholds."""
    import pybullet as p

    cid = p.connect(p.DIRECT)
    try:
        h = 1.0 / 240.0
        p.setPhysicsEngineParameter(fixedTimeStep=h, numSolverIterations=60, deterministicOverlappingPairs=1, physicsClientId=cid)
        p.setGravity(0, 0, -9.81, physicsClientId=cid)
        V = np.array([[sx * BOX_HALF[0], sy * BOX_HALF[1], sz * BOX_HALF[2]] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        box = p.createMultiBody(0.3, p.createCollisionShape(p.GEOM_MESH, vertices=V.tolist(), physicsClientId=cid),
                                basePosition=[0, 0, BOX_HALF[2]], physicsClientId=cid)
        p.changeDynamics(box, -1, lateralFriction=1.0, restitution=e, physicsClientId=cid)
        table = p.createMultiBody(0, p.createCollisionShape(p.GEOM_PLANE, physicsClientId=cid), physicsClientId=cid)
        p.changeDynamics(table, -1, lateralFriction=0.0, restitution=1.0, physicsClientId=cid)
        r = 0.0195
        sph = p.createMultiBody(10.0, p.createCollisionShape(p.GEOM_SPHERE, radius=r, physicsClientId=cid),
                                basePosition=[-BOX_HALF[0] - r - start_gap, 0, BOX_HALF[2]], physicsClientId=cid)
        p.changeDynamics(sph, -1, lateralFriction=0.0, restitution=1.0, physicsClientId=cid)
        p.setCollisionFilterPair(sph, table, -1, -1, 0, physicsClientId=cid)
        p.resetBaseVelocity(sph, [v, 0, 0], [0, 0, 0], physicsClientId=cid)
        for _ in range(int(0.3 / h)):
            p.applyExternalForce(sph, -1, [0, 0, 10.0 * 9.81], [0, 0, 0], p.LINK_FRAME, physicsClientId=cid)
            p.stepSimulation(physicsClientId=cid)
        return p.getBaseVelocity(box, physicsClientId=cid)[0][0] / v
    finally:
        p.disconnect(cid)


def _loop_launch(sim, v: float, e: float, start_gap: float) -> float:
    """Launch speed / v of the box struck by the loop's path-driven sphere (SimRequest, frictionless table)."""
    import trimesh

    from service.mesh import Mesh
    from service.model import ObjectModel
    from service.residuals.types import RobotPath, SimRequest
    from service.session.types import Friction
    from service.transforms import make_X

    m = Mesh.from_trimesh(trimesh.creation.box(np.array(BOX_HALF) * 2))
    I = np.diag([0.3 / 3 * (BOX_HALF[1] ** 2 + BOX_HALF[2] ** 2), 0.3 / 3 * (BOX_HALF[0] ** 2 + BOX_HALF[2] ** 2),
                 0.3 / 3 * (BOX_HALF[0] ** 2 + BOX_HALF[1] ** 2)])
    model = ObjectModel(m, (m,), 0.3, True, np.zeros(3), I, Friction(0.0, 0.15), {})
    r = 0.0195
    rt = np.arange(0.0, 1.0, 1e-3)
    x0 = -BOX_HALF[0] - r - start_gap
    tb = (start_gap + 0.02) / v
    tau = np.clip(rt - tb, 0.0, v / 12.0)
    s = np.where(rt < tb, v * rt, v * tb + v * tau - 6.0 * tau**2)
    path = RobotPath(rt, np.stack([x0 + s, np.zeros_like(rt), np.full_like(rt, BOX_HALF[2])], 1), None, r)
    t = np.arange(0.0, 0.5, 1 / 30)
    X = sim(SimRequest(model, make_X(np.eye(3), np.array([0, 0, BOX_HALF[2]])), np.zeros(3), np.zeros(3), t, 0.0, path,
                       {"restitution": e, "friction_object_table": 0.0}))
    return float((X[-1, 0, 3] - X[-4, 0, 3]) / (t[-1] - t[-4]) / v)


def phases(args) -> None:
    from service.residuals.simulate import BulletSimulator

    gaps = 0.03 + np.random.default_rng(args.seed).uniform(0.0, 0.005, args.phases)
    for v in args.speeds:
        rows = [("lab settings (4.17 ms, restitution threshold 0.2 m/s, contact breaking 0.02 m)", None, None)]
        rows += [(f"loop's simulator, contact breaking {'0.02 m (Bullet)' if cb is None else f'{cb * 1e3:g} mm'}, contact "
                  "erp Bullet", cb, None) for cb in (None, 0.001)]
        rows += [("loop's simulator, contact breaking 1 mm, sub-step split at the touch (touch_split)", 0.001, "split")]
        for name, cb, erp in rows:
            if name.startswith("lab"):
                l0 = np.array([_lab_like_launch(v, 0.0, g) for g in gaps])
                q = np.array([_lab_like_launch(v, E_TRUE, g) for g in gaps]) / l0
            else:
                with BulletSimulator(0.002, contact_breaking_m=cb, touch_split=erp == "split") as sim:
                    l0 = np.array([_loop_launch(sim, v, 0.0, g) for g in gaps])
                    q = np.array([_loop_launch(sim, v, E_TRUE, g) for g in gaps]) / l0
            print(f"v {v:.2f} m/s, {name}: launch(e=0.3)/launch(e=0) mean {q.mean():.3f}, bounce lost (< 1.1) in "
                  f"{int((q < 1.1).sum())}/{len(q)}, partly (1.1-1.25) in {int(((q >= 1.1) & (q < 1.25)).sum())}; "
                  + " ".join(f"{x:.2f}" for x in q) + f"; launch(e=0)/v {l0.min():.3f}-{l0.max():.3f}", flush=True)


def lab(args) -> None:
    from service.synth import sim
    from tests.synth.strike_lab import lab_strike

    phases = (np.arange(args.phases) + 0.5) / args.phases
    height = None if args.height_frac is None else args.height_frac * 0.125
    m_ratio = sim.STRIKE_EE_MASS / (sim.STRIKE_EE_MASS + 0.3)
    saved = sim.STRIKE_CONTACT_PROCESSING_M
    saved_law = sim.STRIKE_CONTACT_STIFFNESS_DAMPING
    saved_split = sim.STRIKE_TOUCH_SPLIT

    def use(setting: str) -> None:
        sim.STRIKE_CONTACT_PROCESSING_M = None if setting in ("bullet", "split") else sim.STRIKE_TOUCH_PROCESSING_M
        sim.STRIKE_CONTACT_STIFFNESS_DAMPING = sim.STRIKE_VELOCITY_ONLY if setting == "velocity" else None
        sim.STRIKE_TOUCH_SPLIT = setting == "split"

    try:
        ref = {}
        if args.reference:  # the same strikes with the step split at the touch and N physics steps per lab step
            use("split")
            for v in args.speeds:
                for e in [0.0, *args.restitutions]:
                    ref[v, e] = np.array([lab_strike(v, e, ph, mu=args.mu, height=height, substeps=args.reference)[1]
                                          for ph in phases])
        for setting, brk in [(s_, b_) for s_ in args.sphere_contact for b_ in args.breaking]:
            use(setting)
            cb = None if brk == "off" else float(brk)
            for v in args.speeds:
                r0 = np.array([lab_strike(v, 0.0, ph, mu=args.mu, height=height, breaking=cb) for ph in phases])
                if ref:
                    q = r0[:, 1] / ref[v, 0.0]
                    print(f"sphere contact {setting}, breaking {brk}, command {v:.2f} m/s: launch / reference (split, "
                          f"{args.reference} steps per lab step) e=0 {q.min():.4f}-{q.max():.4f}", end="", flush=True)
                q0 = r0[:, 1] / r0[:, 0]
                line = (f"sphere contact {setting}, breaking {brk}, command {v:.2f} m/s (approach {r0[:, 0].mean():.3f} m/s): e=0 launch/approach "
                        f"{q0.min():.3f}-{q0.max():.3f} (heavy striker through the CoM: {m_ratio:.3f})")
                for e in args.restitutions:
                    re = np.array([lab_strike(v, e, ph, mu=args.mu, height=height, breaking=cb) for ph in phases])
                    if ref:
                        qr = re[:, 1] / ref[v, e]
                        print(f", e={e:g} {qr.min():.4f}-{qr.max():.4f}", end="", flush=True)
                    q = re[:, 1] / r0[:, 1]
                    line += (f"; e={e:g}: launch/launch(e=0) mean {q.mean():.3f} min {q.min():.3f} max {q.max():.3f}, bounce lost "
                             f"(< 1 + e/2) in {int((q < 1 + e / 2).sum())}/{len(q)}, partly (< 1 + 0.9 e) in "
                             f"{int(((q >= 1 + e / 2) & (q < 1 + 0.9 * e)).sum())}; launch/approach "
                             f"{(re[:, 1] / re[:, 0]).min():.3f}-{(re[:, 1] / re[:, 0]).max():.3f}")
                if ref:
                    print(flush=True)
                print(line, flush=True)
    finally:
        sim.STRIKE_CONTACT_PROCESSING_M = saved
        sim.STRIKE_CONTACT_STIFFNESS_DAMPING = saved_law
        sim.STRIKE_TOUCH_SPLIT = saved_split


def _lab_rest(breaking: float | None, margin: float, tilt: float) -> tuple:
    """(creep mm, turn deg, CoM height - exact rest height mm, mean object-table points, their changes) over the
    second of 2 s at rest, and the deceleration (m/s^2) of a slide launched at 0.5 m/s, for the lab's baking box."""
    import tempfile

    import pybullet as p

    from service.synth import sim
    from service.synth.objects import make_object
    from service.transforms import make_X, mat_to_quat, quat_to_xyzw, so3_exp

    h = 1.0 / 240.0
    obj = make_object("baking_box")
    cid = p.connect(p.DIRECT)
    tmp = tempfile.TemporaryDirectory(prefix="vysics-rest-")
    try:
        sim.configure_world(cid, h, np.array([0.0, 0.0, -sim.GRAVITY]))
        if breaking is not None:
            p.setPhysicsEngineParameter(contactBreakingThreshold=breaking, physicsClientId=cid)
        tcol = p.createCollisionShape(p.GEOM_BOX, halfExtents=sim.TABLE_HALF, physicsClientId=cid)
        table = p.createMultiBody(0, tcol, -1, [0, 0, -margin - sim.TABLE_HALF[2]], physicsClientId=cid)
        p.changeDynamics(table, -1, lateralFriction=0.15, restitution=1.0, rollingFriction=0.0005, physicsClientId=cid)
        zmin = float(np.asarray(obj.mesh.vertices)[:, 2].min())
        body, _, _, _ = sim.add_object(cid, obj, make_X(np.eye(3), np.array([0, 0, -zmin + 0.0002])), np.zeros(3), 0.3, tmp.name)
        if margin != sim.HULL_MARGIN:
            p.changeDynamics(body, -1, collisionMargin=margin, physicsClientId=cid)
        if tilt:
            ps, q0 = p.getBasePositionAndOrientation(body, physicsClientId=cid)
            R0 = np.array(p.getMatrixFromQuaternion(q0)).reshape(3, 3)
            q = mat_to_quat(so3_exp(np.array([tilt, 0.0, 0.0])) @ R0)
            p.resetBasePositionAndOrientation(body, [ps[0], ps[1], ps[2] + 0.0325 * abs(np.sin(tilt)) + 0.0005],
                                              quat_to_xyzw(q), physicsClientId=cid)
        else:  # the lab's settling
            p.changeDynamics(body, -1, linearDamping=0.9, angularDamping=0.9, physicsClientId=cid)
            for _ in range(int(0.8 / h)):
                p.stepSimulation(physicsClientId=cid)
            p.changeDynamics(body, -1, linearDamping=0.0, angularDamping=0.0, physicsClientId=cid)
            p.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0], physicsClientId=cid)
            for _ in range(int(0.2 / h)):
                p.stepSimulation(physicsClientId=cid)
        P, nc = [], []
        for _ in range(int(2.0 / h)):
            p.stepSimulation(physicsClientId=cid)
            P.append(p.getBasePositionAndOrientation(body, physicsClientId=cid))
            nc.append(len(p.getContactPoints(body, table, physicsClientId=cid)))
        pos, qs, half = np.array([x[0] for x in P]), np.array([x[1] for x in P]), len(P) // 2
        creep = 1e3 * float(np.linalg.norm(pos[-1, :2] - pos[half, :2]))
        turn = float(np.degrees(2 * np.arccos(np.clip(abs(np.sum(qs[-1] * qs[half])), 0.0, 1.0))))
        p.resetBaseVelocity(body, [0.5, 0, 0], [0, 0, 0], physicsClientId=cid)
        V = []
        for _ in range(int(0.4 / h)):
            p.stepSimulation(physicsClientId=cid)
            V.append(p.getBaseVelocity(body, physicsClientId=cid)[0][0])
        V, t = np.array(V), np.arange(len(V)) * h
        m = (V > 0.05) & (t > 0.02)
        return (creep, turn, 1e3 * (pos[-1, 2] + zmin), float(np.mean(nc[half:])), int((np.diff(nc[half:]) != 0).sum()),
                float(-np.polyfit(t[m], V[m], 1)[0]))
    finally:
        p.disconnect(physicsClientId=cid)
        tmp.cleanup()


def lab_rest(args) -> None:
    from service.synth import sim

    for name, cb, margin in (("Bullet's default (0.02), margin 1 mm (the lab)", None, sim.HULL_MARGIN),
                             ("breaking 0.005, margin 1 mm", 0.005, sim.HULL_MARGIN),
                             ("breaking 0.002, margin 1 mm", 0.002, sim.HULL_MARGIN),
                             ("breaking 0.001, margin 1 mm", 0.001, sim.HULL_MARGIN),
                             ("breaking 0.001, margin 0.1 mm", 0.001, 1e-4),
                             ("breaking 0.001, margin 0", 0.001, 0.0)):
        for tilt, start in ((0.0, "settled"), (0.005, "released tilted 5 mrad"), (0.3, "released 0.3 rad on an edge")):
            c, tu, z, n, ch, a = _lab_rest(cb, margin, tilt)
            print(f"{name}, {start}: second s at rest: creep {c:.3f} mm, turn {tu:.3f} deg, CoM {z:+.2f} mm from its "
                  f"rest height, object-table points {n:.2f} ({ch} changes); slide from 0.5 m/s: {a:.3f} m/s^2 "
                  f"(mu g {0.15 * sim.GRAVITY:.3f})", flush=True)


def blocks(args) -> None:
    from service.residuals.effects import REGISTRY
    from service.residuals.loop import Evaluator, effect_mask, make_segments, reduce_blocks, smooth_robot
    from service.residuals.modes import classify, object_radius
    from service.residuals.simulate import BulletSimulator
    from service.residuals.types import ResidualConfig, ResidualInputs
    from service.synth.types import HiddenEffects, SynthSpec
    from tests.residuals.synthlab import lab_session, perturbed_model

    grid = np.array([0.0, 0.1, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5])
    if args.lab_strike_contact != "bullet":  # docs/residuals-findings.md, "The synthetic lab's strikes", "The launch kick"
        from service.synth import sim as lab_sim

        if args.lab_strike_contact == "split":  # "A strike's contact that starts at the touch"
            lab_sim.STRIKE_TOUCH_SPLIT = True
        else:
            lab_sim.STRIKE_CONTACT_PROCESSING_M = lab_sim.STRIKE_TOUCH_PROCESSING_M
        if args.lab_strike_contact == "velocity":
            lab_sim.STRIKE_CONTACT_STIFFNESS_DAMPING = lab_sim.STRIKE_VELOCITY_ONLY
    for seed in args.seeds:
        ls = lab_session(SynthSpec(object="baking_box", interaction="strike", seed=seed, preset="tiny", n_frames=900,
                                   friction_object_table=0.15, effects=HiddenEffects(restitution=E_TRUE)),
                         pose_noise_m=args.pose_noise, pose_noise_rad=10.0 * args.pose_noise)
        model = perturbed_model(ls)
        cfg = dataclasses.replace(ResidualConfig.fast(), candidates=("restitution",), segment_s=0.3, seed=seed)
        robot = smooth_robot(ls.robot, cfg)
        inp = ResidualInputs(model, (ls.trajectory,), ls.table_height, robot=(robot,))
        segs = make_segments(inp, [classify(model, ls.trajectory, ls.table_height, robot, cfg)], cfg)
        eff = REGISTRY["restitution"]
        masks = [effect_mask(sg, eff) for sg in segs]
        keep = [i for i, m in enumerate(masks) if m.sum() >= 3]
        S, M = [segs[i] for i in keep], [masks[i] for i in keep]
        for cb in args.contact_breaking:
            cbv = None if cb == "off" else float(cb)
            with BulletSimulator(cfg.sim_substep_s, contact_breaking_m=cbv, touch_split=args.touch_split) as sim:
                ev = Evaluator(sim, ls.table_height, object_radius(model))
                E = np.array([reduce_blocks(ev.frame_scalar(model, {"restitution": e}, S), M) for e in grid]) * 1e3
            i3 = int(np.flatnonzero(grid == E_TRUE)[0])
            best = grid[np.argmin(E, 0)]
            print(f"seed {seed}, pose noise {args.pose_noise * 1e3:g} mm, contact breaking {cb}: {len(S)} blocks where "
                  f"restitution acts; block error e=0 {E[0].mean():.2f} mm (median {np.median(E[0]):.2f}), true e "
                  f"{E[i3].mean():.2f} mm (median {np.median(E[i3]):.2f}), true/e=0 {E[i3].mean() / E[0].mean():.2f}, "
                  f"better/worse {int((E[i3] < E[0]).sum())}/{int((E[i3] > E[0]).sum())}; each block's best e in the "
                  f"grid: {' '.join(f'{b:.2f}' for b in best)} (median {np.median(best):.2f}), its error {E.min(0).mean():.2f} mm",
                  flush=True)


def main() -> None:
    from _overrides import nonnegative_float, off_or_positive, positive_float, positive_int, unit_float

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    ph = sub.add_parser("phases")
    ph.add_argument("--speeds", type=positive_float, nargs="+", default=[0.35, 0.45, 0.6])
    ph.add_argument("--phases", type=positive_int, default=12)
    ph.add_argument("--seed", type=int, default=2)
    bl = sub.add_parser("blocks")
    bl.add_argument("--seeds", type=int, nargs="+", default=[666, 667])
    bl.add_argument("--pose-noise", type=nonnegative_float, default=0.0)
    bl.add_argument("--contact-breaking", type=off_or_positive, nargs="+", default=["off", 0.001])
    bl.add_argument("--lab-strike-contact", choices=("touch", "velocity", "split", "bullet"), default="bullet",
                    help="the lab's sphere-object contact: from the touch on, from the touch on at the velocity level "
                         "only (no push-out of the overlap), or as Bullet makes it (the lab's default)")
    bl.add_argument("--touch-split", action="store_true",
                    help="the loop's sub-step split at the sphere's time of impact (ResidualConfig.touch_split; on in the "
                         "loop by default, off in this sweep unless given)")
    lb = sub.add_parser("lab")
    lb.add_argument("--speeds", type=positive_float, nargs="+", default=[0.4, 0.55, 0.7], help="commanded strike speeds, m/s")
    lb.add_argument("--phases", type=positive_int, default=12)
    lb.add_argument("--restitutions", type=unit_float, nargs="+", default=[0.1, 0.3, 0.5])
    lb.add_argument("--sphere-contact", nargs="+", choices=("bullet", "touch", "velocity", "split"), default=["bullet", "touch"],
                    help="bullet: every point as Bullet makes it (the lab's default); touch: from the touch on, the "
                         "overlap pushed out through the velocity; velocity: from the touch on, velocity level only; "
                         "split: the step split at the time of impact (sim.STRIKE_TOUCH_SPLIT)")
    lb.add_argument("--reference", type=positive_int, default=None, metavar="N",
                    help="also print each launch over the same strike's with the step split at the touch and N physics "
                         "steps per lab step (a reference near the continuous physics)")
    lb.add_argument("--breaking", type=off_or_positive, nargs="+", default=["off"], help="Bullet's contact breaking threshold(s) for the whole "
                    "world (a factor of each shape's bounding radius), or 'off' for Bullet's 0.02")
    lb.add_argument("--mu", type=nonnegative_float, default=0.0, help="table friction")
    lb.add_argument("--height-frac", type=unit_float, default=None, help="contact height / box height (default: the CoM's)")
    sub.add_parser("lab-rest")
    args = ap.parse_args()
    print("command: python benchmarks/strike_restitution.py " + " ".join(sys.argv[1:]), flush=True)
    {"phases": phases, "blocks": blocks, "lab": lab, "lab-rest": lab_rest}[args.cmd](args)


if __name__ == "__main__":
    main()
