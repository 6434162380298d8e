"""Diagnosis of the angular damping fitted high on strikes (docs/residuals-findings.md, "Angular damping on strikes: where
the fit's excess comes from"): the damping law of the lab and of the loop's replay, the spin a struck box keeps in the
lab and in the replay, and where the damping's training loss has its minimum.

Ground truth is read here only (the hidden damping, noise-free poses); nothing of it reaches the loop. Baking-box
strike sessions of the synthetic lab (30 s, 30 Hz, the strike benchmark's settings), catalogue model, declared friction
0.15; the loop's replay defaults (``simulate.simulator_for(ResidualConfig.fast())``) unless ``--cfg``.

    python benchmarks/strike_spin.py flight [--b 2.0]
        a box spinning at 4 rad/s in free flight for 0.5 s with the damping b: the lab's explicit torque at its 240 Hz
        step against the replay's at its sub-step and the exact e^(-b t) (same law, same kind of step)
    python benchmarks/strike_spin.py grid --seeds 780 781 782 783 [--hidden 2.0] [--pose-noise 0] [--self [--mu-scatter S]]
        [--grid 1.6 1.8 2.0 2.2 2.4 2.6 2.8 3.0 3.2] [--physics-hz 240] [--cfg JSON]
        the mean block error (position + rho * angle, the fit's loss, on the effect's frames of every block where it
        acts) at each damping of the grid, with the hidden damping in the lab; --self: the data are the replay's own
        rollouts of the true model plus the pose noise (what the noise and the loss alone do to the minimum), each block's
        with the table friction scattered by --mu-scatter S (relative, normal) if given: a random mismatch of the slides
    python benchmarks/strike_spin.py profile --seeds 780 781 782 783 [--hidden 0] [--b B] [--physics-hz 240]
        [--cfg JSON]
        launch blocks that turn the box by 10 degrees or more (noise-free poses): the mean yaw increment per frame after
        the onset in the lab and in the replay of the model with damping B (default: the hidden one), and the tilt
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _yaw_deg(X: np.ndarray, R0: np.ndarray) -> np.ndarray:
    """(T,) rotation about world z of X[:, :3, :3] relative to R0 (deg, unwrapped; the box stands on a face)."""
    D = X[:, :3, :3] @ R0.T
    return np.degrees(np.unwrap(np.arctan2(D[:, 1, 0], D[:, 0, 0])))


def _tilt_deg(X: np.ndarray) -> np.ndarray:
    """(T,) angle between world z and the body axis closest to it (deg)."""
    return np.degrees(np.arccos(np.clip(np.max(np.abs(X[:, 2, :3]), axis=1), -1.0, 1.0)))


def _setup(seed: int, hidden: float, pose_noise: float, physics_hz: float, cfg_json: str):
    """(lab session, model, loop config, blocks, simulator, evaluator) of one strike session with the hidden damping."""
    from service.residuals.loop import Evaluator, make_segments, smooth_robot
    from service.residuals.modes import classify, object_radius
    from service.residuals.simulate import simulator_for
    from service.residuals.types import ResidualConfig, ResidualInputs
    from service.synth.types import HiddenEffects, SynthSpec
    from tests.residuals.synthlab import lab_session, perturbed_model

    spec = SynthSpec(object="baking_box", interaction="strike", seed=seed, preset="tiny", n_frames=900,
                     friction_object_table=0.15, physics_hz=physics_hz,
                     effects=HiddenEffects(angular_damping=hidden))
    ls = lab_session(spec, pose_noise_m=pose_noise, pose_noise_rad=10.0 * pose_noise)
    cfg = dataclasses.replace(ResidualConfig.fast(), candidates=("angular_damping",), segment_s=0.3, seed=seed,
                              fit_maxiter=24, max_train_segments=10, **json.loads(cfg_json))
    model = perturbed_model(ls)
    robot = smooth_robot(ls.robot, cfg)
    inp = ResidualInputs(model, (ls.trajectory,), ls.table_height, robot=(robot,))
    segs = make_segments(inp, [classify(model, ls.trajectory, ls.table_height, robot, cfg)], cfg)
    sim = simulator_for(cfg)
    return ls, model, cfg, segs, sim, Evaluator(sim, ls.table_height, object_radius(model))


def _with_b(model, b: float):
    from service.residuals.effects import apply_effects

    m1, e1 = apply_effects(model, {"angular_damping": (b,)})
    return m1, {**model.effects, **e1}


def flight(args) -> None:
    import pybullet as pb

    from service.mesh import Mesh
    from service.model import ObjectModel
    from service.residuals.simulate import BulletSimulator
    from service.residuals.types import SimRequest
    from service.session.types import Friction
    from service.synth import sim as lab
    from service.synth.objects import make_object
    from service.transforms import make_X, pose_from_xyzw, quat_from_xyzw, quat_to_mat

    obj = make_object("baking_box")
    b, w0, T, hz = args.b, np.array([0.0, 0.0, 4.0]), 0.5, 240.0
    cid = pb.connect(pb.DIRECT)
    try:
        lab.configure_world(cid, 1.0 / hz, np.zeros(3))
        with tempfile.TemporaryDirectory() as tmp:
            body, X_MI, _, evals = lab.add_object(cid, obj, make_X(np.eye(3), np.array([0.0, 0.0, 1.0])), np.zeros(3),
                                                  0.0, tmp)
        pb.resetBaseVelocity(body, [0, 0, 0], w0.tolist(), physicsClientId=cid)
        for _ in range(int(round(T * hz))):  # the lab's law: tau = -b R I R^T w before every step
            q = pb.getBasePositionAndOrientation(body, physicsClientId=cid)[1]
            w = np.asarray(pb.getBaseVelocity(body, physicsClientId=cid)[1])
            R = quat_to_mat(quat_from_xyzw(q))
            pb.applyExternalTorque(body, -1, (-b * (R @ (evals * (R.T @ w)))).tolist(), pb.WORLD_FRAME,
                                   physicsClientId=cid)
            pb.stepSimulation(physicsClientId=cid)
        w_lab = float(pb.getBaseVelocity(body, physicsClientId=cid)[1][2])
        pos, orn = pb.getBasePositionAndOrientation(body, physicsClientId=cid)
        X_lab = pose_from_xyzw(pos, orn) @ np.linalg.inv(X_MI)
    finally:
        pb.disconnect(cid)
    inertia = np.asarray(obj.mesh.moment_inertia, float) * (obj.mass / obj.mesh.mass)
    model = ObjectModel(Mesh.from_trimesh(obj.mesh), (), obj.mass, True, np.zeros(3), inertia, Friction(0.15, 0.15), {})
    with BulletSimulator(0.002) as sim:
        t = np.linspace(0.0, T, 16)  # 30 Hz frames, the loop's sub-step 1.96 ms
        X = sim(SimRequest(model, make_X(np.eye(3), np.array([0.0, 0.0, 1.0])), np.zeros(3), w0, t, -10.0, None,
                           {"angular_damping": b, "gravity_scale": 0.0}))
    yl = float(np.arctan2(X_lab[1, 0], X_lab[0, 0]))
    yr = float(np.arctan2(X[-1, 1, 0], X[-1, 0, 0]))
    exact = w0[2] / b * (1.0 - np.exp(-b * T))
    print(f"free spin 4 rad/s, b = {b} /s, {T} s: lab w(T) {w_lab:.4f} rad/s (exact {w0[2] * np.exp(-b * T):.4f}); "
          f"turned: lab {yl:.4f}, replay {yr:.4f}, exact {exact:.4f} rad "
          f"(lab {yl / exact - 1:+.2%}, replay {yr / exact - 1:+.2%})")


def grid(args) -> None:
    from service.residuals.effects import REGISTRY
    from service.residuals.loop import effect_mask, reduce_blocks
    from service.transforms import so3_exp

    eff = REGISTRY["angular_damping"]
    for seed in args.seeds:
        ls, model, cfg, segs, sim, ev = _setup(seed, args.hidden, args.pose_noise, args.physics_hz, args.cfg)
        try:
            masks = [effect_mask(sg, eff) for sg in segs]
            keep = [i for i, m in enumerate(masks) if m.sum() >= 3]
            segs, masks = [segs[i] for i in keep], [masks[i] for i in keep]
            if args.self:  # the replay's own rollouts of the true model as the data, with the pose noise
                rs = np.random.default_rng(seed + 7)
                m2, e2 = _with_b(model, args.hidden)
                new = []
                for sg in segs:  # --mu-scatter: each block's data with its own table friction (a random mismatch)
                    mu_k = 0.15 * (1.0 + args.mu_scatter * rs.standard_normal())
                    Xr = ev.rollout(m2, {**e2, "friction_object_table": mu_k} if args.mu_scatter else e2, sg).copy()
                    Xr[:, :3, 3] += rs.normal(scale=args.pose_noise, size=(len(Xr), 3))
                    Xr[:, :3, :3] = so3_exp(rs.normal(scale=10.0 * args.pose_noise, size=(len(Xr), 3))) @ Xr[:, :3, :3]
                    new.append(dataclasses.replace(sg, X_obs=Xr))
                segs = new
            rows = []
            for b in args.grid:
                fs = ev.frame_split(*_with_b(model, b), segs)
                pos = float(np.nanmean(reduce_blocks([f[:, 0] for f in fs], masks)))
                rot = float(np.nanmean(reduce_blocks([f[:, 1] for f in fs], masks)))
                rows.append((b, pos, rot))
        finally:
            sim.close()
        best = min(rows, key=lambda r: r[1] + r[2])
        print(f"seed {seed} (hidden {args.hidden}, pose noise {args.pose_noise}, lab {args.physics_hz:g} Hz"
              f"{', self' if args.self else ''}{f', mu scatter {args.mu_scatter:g}' if args.mu_scatter else ''}; "
              f"{len(segs)} blocks): "
              + "  ".join(f"{b:g}: {(p + r) * 1e3:.2f}" for b, p, r in rows)
              + f" mm  | minimum at {best[0]:g} (rotation part there {best[2] * 1e3:.2f} mm)", flush=True)


def profile(args) -> None:
    b_rep = args.hidden if args.b is None else args.b
    L, P, TL, TP = [], [], [], []
    n = 10
    for seed in args.seeds:
        ls, model, cfg, segs, sim, ev = _setup(seed, args.hidden, 0.0, args.physics_hz, args.cfg)
        try:
            m1, e1 = _with_b(model, b_rep)
            for s in segs:
                if len(s.t) <= 10:  # launch blocks only (regular blocks are 0.3 s: 9-10 frames)
                    continue
                R0 = s.X_obs[0, :3, :3]
                yl = _yaw_deg(s.X_obs, R0)
                if abs(yl[-1]) < 10.0:
                    continue
                X = ev.rollout(m1, e1, s)
                yr = _yaw_deg(X, R0)
                k0 = int(np.argmax(np.linalg.norm(np.diff(s.X_obs[:, :3, 3], axis=0), axis=1) > 0.002))
                sg = np.sign(yl[-1])
                pad = lambda v: np.pad(v[:n], (0, n - len(v[:n])))  # noqa: E731
                L.append(pad(sg * np.diff(yl)[k0:]))
                P.append(pad(sg * np.diff(yr)[k0:]))
                TL.append(pad(_tilt_deg(s.X_obs)[k0 + 1:]))
                TP.append(pad(_tilt_deg(X)[k0 + 1:]))
        finally:
            sim.close()
    L, P = np.array(L), np.array(P)
    print(f"{len(L)} launch blocks turning >= 10 deg (seeds {' '.join(map(str, args.seeds))}; hidden {args.hidden} /s, "
          f"replay {b_rep} /s, lab {args.physics_hz:g} Hz)")
    print("frame after the onset         ", list(range(n)))
    print("lab: mean yaw increment, deg  ", np.round(L.mean(0), 2).tolist())
    print("replay                        ", np.round(P.mean(0), 2).tolist())
    print("replay - lab, cumulative      ", np.round(np.cumsum(P.mean(0) - L.mean(0)), 2).tolist())
    print("lab: mean tilt, deg           ", np.round(np.mean(TL, 0), 2).tolist())
    print("replay                        ", np.round(np.mean(TP, 0), 2).tolist())
    print(f"turned in all: lab {L.sum(1).mean():.2f} deg, replay {P.sum(1).mean():.2f} deg "
          f"(replay / lab {P.sum(1).mean() / L.sum(1).mean():.3f})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    f = sub.add_parser("flight")
    f.add_argument("--b", type=float, default=2.0)
    for name in ("grid", "profile"):
        p = sub.add_parser(name)
        p.add_argument("--seeds", type=int, nargs="+", default=[780, 781, 782, 783])
        p.add_argument("--hidden", type=float, default=2.0 if name == "grid" else 0.0)
        p.add_argument("--physics-hz", type=float, default=240.0, help="the lab's physics rate (a multiple of 30)")
        p.add_argument("--cfg", default="{}", help="ResidualConfig fields for the replay, as JSON")
    g = sub.choices["grid"]
    g.add_argument("--pose-noise", type=float, default=0.0, help="m (and 10x that in rad), as the strike benchmark")
    g.add_argument("--self", action="store_true")
    g.add_argument("--mu-scatter", type=float, default=0.0,
                   help="with --self: each block's data made with the table friction 0.15 (1 + s z), z ~ N(0, 1)")
    g.add_argument("--grid", type=float, nargs="+", default=[1.6, 1.8, 2.0, 2.2, 2.4, 2.6, 2.8, 3.0, 3.2])
    sub.choices["profile"].add_argument("--b", type=float, default=None)
    args = ap.parse_args()
    {"flight": flight, "grid": grid, "profile": profile}[args.cmd](args)


if __name__ == "__main__":
    main()
