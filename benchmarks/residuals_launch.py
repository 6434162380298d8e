"""Diagnosis of the strike replay (docs/residuals-findings.md, "Linear damping fitted low on strikes"): how fast the
rollouts launch a struck object against the lab, and where the damping's training loss has its minimum.

Ground truth is read here only (the hidden damping, noise-free poses and robot path); nothing of it reaches the
loop. Baking-box strike sessions of the synthetic lab (30 s, 30 Hz, the strike benchmark's settings), catalogue
model, declared friction 0.15 (the true one unless ``--mu``).

    python benchmarks/residuals_launch.py launch --seed 651 [--b 2.0] [--mu 0.15] [--noise] [--drive lead|inverse]
        [--contact-breaking M|off] [--substep 0.002] [--smooth S] [--smooth-weights box|biweight]
        per launch block: the observed horizontal travel and peak frame speed against the rollout of the true model
        (noise-free poses and robot path, no smoothing unless --noise / --smooth)
    python benchmarks/residuals_launch.py loss --seed 651 [--b 2.0] [--pose-noise 5e-4] [--no-robot-noise]
        [--drive lead|inverse] [--contact-breaking M|off] [--smooth 0.04] [--smooth-weights box|biweight]
        [--grid 0 1.4 1.7 2.0 2.3 2.6]
        the damping's training loss (the loop's blocks, start states and error) at each b of the grid, on the frames
        it is fitted on and split by frame kind (sliding, robot contact, rest, all, the last frame of each launch)
    python benchmarks/residuals_launch.py path --seeds 681 682 683 [--smooth 0.04] [--smooth-weights box|biweight]
        no rollout: the robot path the loop smooths, with and without the lab's sensor noise, against the true path —
        the velocity noise its sample-to-sample increments keep, and per strike the launch a kinematic sphere on it
        would hand a free 1-D object (pushed whenever the sphere reaches it, sliding with mu g = 1.47 m/s² otherwise)
The subcommands' defaults are the loop's former replay settings (the lead drive, Savitzky-Golay over 0.04 s), the ones
this script's figures were made with; the loop's defaults now (docs/residuals-findings.md, "The split and the inverse drive
together"): --drive inverse --smooth-weights biweight --smooth 0.08. The rollouts are the loop's simulator (``simulate.simulator_for``) with its contact breaking threshold
(1 mm by default) unless ``--contact-breaking M|off``; the figures of "Linear damping fitted low on strikes" were made
before 1 mm became the default, with Bullet's 0.02 m: ``--contact-breaking off`` replays so.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _session(seed: int, b: float, mu: float, pose_noise: float, robot_noise: bool):
    from service.synth.types import HiddenEffects, SynthSpec
    from tests.residuals.synthlab import lab_session

    hidden = {"linear_damping": b} if b > 0 else {}
    if mu != 0.15:
        hidden["friction_object_table"] = mu
    spec = SynthSpec(object="baking_box", interaction="strike", seed=seed, preset="tiny", n_frames=900,
                     friction_object_table=0.15, effects=HiddenEffects(**hidden), noise=robot_noise)
    return lab_session(spec, pose_noise_m=pose_noise, pose_noise_rad=10.0 * pose_noise)


def _blocks(ls, model, cfg):
    from service.residuals.loop import launches, make_segments, smooth_robot
    from service.residuals.modes import classify
    from service.residuals.types import ResidualInputs

    robot = smooth_robot(ls.robot, cfg)
    tr = ls.trajectory
    mode = classify(model, tr, ls.table_height, robot, cfg)
    segs = make_segments(ResidualInputs(model, (tr,), ls.table_height, robot=(robot,)), [mode], cfg)
    starts = {max(a - cfg.launch_lead, 0) for a, _ in launches(np.asarray(tr.t), np.asarray(tr.X_WO),
                                                                np.ones(len(tr.t), bool), cfg)}
    return segs, starts, mode


def launch(args) -> None:
    from service.residuals.effects import apply_effects
    from service.residuals.simulate import simulator_for
    from service.residuals.types import ResidualConfig, SimRequest
    from service.session.types import Friction
    from tests.residuals.synthlab import perturbed_model

    ls = _session(args.seed, args.b, args.mu, 5e-4 if args.noise else 0.0, args.noise)
    smooth = args.smooth if args.smooth is not None else (0.04 if args.noise else 0.0)
    cfg = dataclasses.replace(ResidualConfig.fast(), segment_s=0.3, robot_smooth_s=smooth, sim_substep_s=args.substep,
                              robot_smooth_weights=args.smooth_weights, sphere_drive=args.drive,
                              **_breaking(args))
    model = perturbed_model(ls)
    model = dataclasses.replace(model, friction=Friction(args.mu, model.friction.object_robot))
    segs, starts, _ = _blocks(ls, model, cfg)
    m1, e1 = apply_effects(model, {"linear_damping": (args.b,)})
    travel, peak = [], []
    with simulator_for(cfg) as sim:
        for s in (s for s in segs if s.start in starts):
            P = s.X_obs[:, :2, 3]
            X = sim(SimRequest(m1, s.X0, s.v0, s.w0, s.t, ls.table_height, s.robot, e1))
            Q = X[:, :2, 3]
            u, us = (np.linalg.norm(np.diff(A, axis=0), axis=1) / np.diff(s.t) for A in (P, Q))
            travel.append(np.linalg.norm(Q[-1] - Q[0]) / np.linalg.norm(P[-1] - P[0]))
            peak.append(us.max() / u.max())
            print(f"  launch block at frame {s.start:4d}: observed travel {np.linalg.norm(P[-1] - P[0]) * 1e3:5.1f} mm, "
                  f"peak frame speed {u.max():.3f} m/s; rollout travel x {travel[-1]:.3f}, peak x {peak[-1]:.3f}")
    print(f"seed {args.seed}, b {args.b} /s, mu {args.mu}, drive {args.drive}, sub-step {args.substep * 1e3:.2f} ms, "
          f"{'noisy poses and robot path' if args.noise else 'noise-free'}, robot path smoothed {smooth:.3f} s "
          f"({args.smooth_weights}): {len(travel)} launches, "
          f"rollout / observed travel median {np.median(travel):.3f} (mean {np.mean(travel):.3f}), peak speed median "
          f"{np.median(peak):.3f}")


def loss(args) -> None:
    from service.residuals.effects import REGISTRY, apply_effects
    from service.residuals.loop import Evaluator, effect_mask
    from service.residuals.modes import object_radius
    from service.residuals.simulate import simulator_for
    from service.residuals.types import MODES, ResidualConfig
    from tests.residuals.synthlab import perturbed_model

    ls = _session(args.seed, args.b, 0.15, args.pose_noise, not args.no_robot_noise)
    cfg = dataclasses.replace(ResidualConfig.fast(), segment_s=0.3, seed=args.seed, fit_maxiter=24, max_train_segments=10)
    cfg = dataclasses.replace(cfg, robot_smooth_s=args.smooth, robot_smooth_weights=args.smooth_weights,
                              sphere_drive=args.drive, **_breaking(args))
    model = perturbed_model(ls)
    segs, starts, _ = _blocks(ls, model, cfg)
    eff = REGISTRY["linear_damping"]
    acts = [(s, effect_mask(s, eff)) for s in segs]
    acts = [(s, m) for s, m in acts if m.sum() >= 3]
    sim = simulator_for(cfg)
    try:
        ev = Evaluator(sim, ls.table_height, object_radius(model))
        res = {}
        for b in args.grid:
            m1, e1 = apply_effects(model, {"linear_damping": (b,)})
            res[b] = ev.frame_split(m1, e1, [s for s, _ in acts])
    finally:
        sim.close()
    print(f"seed {args.seed}, hidden b {args.b} /s, drive {args.drive}, pose noise {args.pose_noise * 1e3:.1f} mm, robot "
          f"noise {'off' if args.no_robot_noise else 'on'}: {len(acts)} blocks where the damping acts "
          f"({sum(s.start in starts for s, _ in acts)} launch blocks); mean block error (mm) at b =",
          " ".join(f"{b:.2f}" for b in args.grid))
    S, RC, R = (MODES.index(x) for x in ("sliding", "robot_contact", "rest"))
    kinds = {
        "its frames (the fit's loss)": lambda s, m: m,
        "sliding frames": lambda s, m: s.mode == S,
        "robot-contact frames": lambda s, m: s.mode == RC,
        "rest frames": lambda s, m: s.mode == R,
        "all frames": lambda s, m: np.ones(len(m), bool),
        "last frame of each launch block": lambda s, m: (np.arange(len(m)) == len(m) - 1) & (s.start in starts),
    }
    for name, sel in kinds.items():
        rows = {"scalar": [], "position": []}
        for b in args.grid:
            sc, po = [], []
            for (s, m), e in zip(acts, res[b]):
                f = sel(s, m) & np.isfinite(e[:, 0])
                if f.any():
                    po.append(e[f, 0].mean())
                    sc.append((e[f, 0] + e[f, 1]).mean())
            rows["scalar"].append(np.mean(sc) * 1e3 if sc else np.nan)
            rows["position"].append(np.mean(po) * 1e3 if po else np.nan)
        for part, v in rows.items():
            best = args.grid[int(np.nanargmin(v))] if np.isfinite(v).any() else float("nan")
            print(f"  {name:32s} {part:8s} " + " ".join(f"{x:6.2f}" for x in v) + f"   minimum at b = {best}")


def _breaking(args) -> dict:
    """``ResidualConfig.contact_breaking_m`` from ``--contact-breaking`` ({} = the loop's default)."""
    if args.contact_breaking is None:
        return {}
    return {"contact_breaking_m": None if args.contact_breaking == "off" else args.contact_breaking}


def _launch_1d(x: np.ndarray, dt: float, i: int, n: int = 20, mu_g: float = 1.47) -> float:
    """Speed (m/s) of a free 1-D object touching a kinematic sphere at sample i of its path x (m along the strike,
    step dt), n samples later: pushed to the sphere's position whenever the sphere reaches it, else sliding."""
    xo, u = x[i], 0.0
    for k in range(i + 1, min(i + n, len(x))):
        u = max(u - mu_g * dt, 0.0)
        if x[k] > xo + u * dt:
            u, xo = (x[k] - xo) / dt, x[k]
        else:
            xo = xo + u * dt
    return u


def path(args) -> None:
    from service.residuals.loop import smooth_robot
    from service.residuals.types import ResidualConfig

    cfg = dataclasses.replace(ResidualConfig(), robot_smooth_s=args.smooth, robot_smooth_weights=args.smooth_weights)
    noise, bias, clean_r, noisy_r = [], [], [], []
    for seed in args.seeds:
        true, noisy = (_session(seed, args.b, 0.15, 0.0, n).robot for n in (False, True))
        dt = float(np.median(np.diff(true.t)))
        v = np.diff(true.p_WE, axis=0) / dt
        vc, vn = (np.diff(smooth_robot(r, cfg).p_WE, axis=0) / dt for r in (true, noisy))
        noise.append(np.sqrt(np.mean(np.sum((vn - vc) ** 2, 1))))
        bias.append(np.sqrt(np.mean(np.sum((vc - v) ** 2, 1))))
        s = np.linalg.norm(v[:, :2], axis=1)
        # strikes: the fastest sample of each approach (the impact follows it)
        peaks = [i for i in range(30, len(s) - 40) if s[i] > 0.25 and s[i] == s[i - 25:i + 25].max()]
        for i in peaks:
            d = v[i, :2] / s[i]
            ref = _launch_1d(true.p_WE[:, :2] @ d, dt, i)
            clean_r.append(_launch_1d(smooth_robot(true, cfg).p_WE[:, :2] @ d, dt, i) / ref)
            noisy_r.append(_launch_1d(smooth_robot(noisy, cfg).p_WE[:, :2] @ d, dt, i) / ref)
    print(f"seeds {args.seeds}, robot path smoothed {args.smooth:.4f} s ({args.smooth_weights}): velocity of the "
          f"sample-to-sample increments, rms noise left {np.mean(noise) * 1e3:.1f} mm/s, rms departure of the noise-free "
          f"smoothed path {np.mean(bias) * 1e3:.1f} mm/s; 1-D launch / the true path's over {len(clean_r)} strikes: "
          f"noise-free median {np.median(clean_r):.4f} (mean {np.mean(clean_r):.4f}), with noise median "
          f"{np.median(noisy_r):.4f} (mean {np.mean(noisy_r):.4f}, sd {np.std(noisy_r):.4f})")


def main() -> None:
    from _overrides import nonnegative_float, off_or_positive, positive_float

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    la = sub.add_parser("launch")
    la.add_argument("--noise", action="store_true", help="the benchmark's pose noise and the lab's robot sensor noise")
    la.add_argument("--mu", type=positive_float, default=0.15)
    la.add_argument("--substep", type=positive_float, default=0.002)
    la.add_argument("--smooth", type=nonnegative_float, default=None,
                    help="window of the robot path's smoothing, s (default: 0.04 with --noise, else 0)")
    lo = sub.add_parser("loss")
    lo.add_argument("--pose-noise", type=nonnegative_float, default=5e-4)
    lo.add_argument("--no-robot-noise", action="store_true")
    lo.add_argument("--smooth", type=nonnegative_float, default=0.04)
    lo.add_argument("--grid", type=nonnegative_float, nargs="+", default=[0.0, 1.4, 1.7, 2.0, 2.3, 2.6])
    pa = sub.add_parser("path")
    pa.add_argument("--seeds", type=int, nargs="+", required=True)
    pa.add_argument("--smooth", type=nonnegative_float, default=0.04)
    pa.add_argument("--b", type=nonnegative_float, default=2.0, help="hidden linear damping, 1/s (0: none)")
    pa.add_argument("--smooth-weights", choices=("box", "biweight"), default="box")
    for p in (la, lo):
        p.add_argument("--seed", type=int, required=True)
        p.add_argument("--b", type=nonnegative_float, default=2.0, help="hidden linear damping, 1/s (0: none)")
        p.add_argument("--drive", choices=("lead", "inverse"), default="lead")
        p.add_argument("--contact-breaking", type=off_or_positive, default=None, metavar="M",
                       help="the rollouts' contact breaking threshold, m, or 'off' for Bullet's 0.02 m "
                            "(default: the loop's, ResidualConfig.contact_breaking_m)")
        p.add_argument("--smooth-weights", choices=("box", "biweight"), default="box",
                       help="weights of the robot path's local quadratic fit (ResidualConfig.robot_smooth_weights)")
    args = ap.parse_args()
    print("command:", " ".join(["python", *sys.argv]))
    {"launch": launch, "loss": loss, "path": path}[args.cmd](args)


if __name__ == "__main__":
    main()
