"""Diagnosis of restitution on strike sessions (docs/residuals.md §6, §7 "Restitution on strikes"). Reads ground truth:
for diagnosis only, never part of the service.

    python benchmarks/strike_restitution.py phases [--speeds 0.35 0.45 0.6] [--phases 12]
    python benchmarks/strike_restitution.py blocks --seeds 666 667 [--pose-noise 0] [--contact-breaking off 0.001]
        [--contact-erp 0.05]

``phases``: a 10 kg sphere strikes a resting 0.3 kg box (9.5 x 6.5 x 12.5 cm) through its CoM on a frictionless table;
the box's launch speed with e = 0.3 over the one with e = 0 (the physics: 1.3 for a heavy striker) over contact
phases (start gaps uniform over 5 mm, so the touch falls anywhere within a sub-step). Rows: the loop's simulator
(``BulletSimulator``: sphere dragged along its path, 2 ms sub-steps) with Bullet's contact breaking threshold, with
1 mm, and with 1 mm and a contact erp of 0.05 (the e = 0 launch over v is printed too: the push-out of a contact that
starts inside the object), and a world with the synthetic lab's settings (240 Hz steps, Bullet's default restitution threshold 0.2 m/s and
contact breaking 0.02 m, a free sphere moving at the strike speed).

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
                  f"erp {'Bullet' if erp is None else erp}", cb, erp) for cb, erp in ((None, None), (0.001, None), (0.001, 0.05))]
        for name, cb, erp in rows:
            if name.startswith("lab"):
                l0 = np.array([_lab_like_launch(v, 0.0, g) for g in gaps])
                q = np.array([_lab_like_launch(v, E_TRUE, g) for g in gaps]) / l0
            else:
                with BulletSimulator(0.002, contact_breaking_m=cb, contact_erp=erp) as sim:
                    l0 = np.array([_loop_launch(sim, v, 0.0, g) for g in gaps])
                    q = np.array([_loop_launch(sim, v, E_TRUE, g) for g in gaps]) / l0
            print(f"v {v:.2f} m/s, {name}: launch(e=0.3)/launch(e=0) mean {q.mean():.3f}, bounce lost (< 1.1) in "
                  f"{int((q < 1.1).sum())}/{len(q)}, partly (1.1-1.25) in {int(((q >= 1.1) & (q < 1.25)).sum())}; "
                  + " ".join(f"{x:.2f}" for x in q) + f"; launch(e=0)/v {l0.min():.3f}-{l0.max():.3f}", flush=True)


def blocks(args) -> None:
    from service.residuals.effects import REGISTRY
    from service.residuals.loop import Evaluator, effect_mask, make_segments, reduce_blocks, smooth_robot
    from service.residuals.modes import classify, object_radius
    from service.residuals.simulate import BulletSimulator
    from service.residuals.types import ResidualConfig, ResidualInputs
    from service.synth.types import HiddenEffects, SynthSpec
    from tests.residuals.synthlab import lab_session, perturbed_model

    grid = np.array([0.0, 0.1, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5])
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
            erp = None if cbv is None or args.contact_erp == "off" else float(args.contact_erp)
            with BulletSimulator(cfg.sim_substep_s, contact_breaking_m=cbv, contact_erp=erp) as sim:
                ev = Evaluator(sim, ls.table_height, object_radius(model))
                E = np.array([reduce_blocks(ev.frame_scalar(model, {"restitution": e}, S), M) for e in grid]) * 1e3
            i3 = int(np.flatnonzero(grid == E_TRUE)[0])
            best = grid[np.argmin(E, 0)]
            print(f"seed {seed}, pose noise {args.pose_noise * 1e3:g} mm, contact breaking {cb}, contact erp "
                  f"{'Bullet' if erp is None else erp}: {len(S)} blocks where "
                  f"restitution acts; block error e=0 {E[0].mean():.2f} mm (median {np.median(E[0]):.2f}), true e "
                  f"{E[i3].mean():.2f} mm (median {np.median(E[i3]):.2f}), true/e=0 {E[i3].mean() / E[0].mean():.2f}, "
                  f"better/worse {int((E[i3] < E[0]).sum())}/{int((E[i3] > E[0]).sum())}; each block's best e in the "
                  f"grid: {' '.join(f'{b:.2f}' for b in best)} (median {np.median(best):.2f}), its error {E.min(0).mean():.2f} mm",
                  flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    ph = sub.add_parser("phases")
    ph.add_argument("--speeds", type=float, nargs="+", default=[0.35, 0.45, 0.6])
    ph.add_argument("--phases", type=int, default=12)
    ph.add_argument("--seed", type=int, default=2)
    bl = sub.add_parser("blocks")
    bl.add_argument("--seeds", type=int, nargs="+", default=[666, 667])
    bl.add_argument("--pose-noise", type=float, default=0.0)
    bl.add_argument("--contact-breaking", nargs="+", default=["off", "0.001"])
    bl.add_argument("--contact-erp", default="off", help="contact erp with a contact breaking threshold set ('off': Bullet's)")
    args = ap.parse_args()
    print("command: python benchmarks/strike_restitution.py " + " ".join(sys.argv[1:]), flush=True)
    phases(args) if args.cmd == "phases" else blocks(args)


if __name__ == "__main__":
    main()
