"""Diagnosis of the error floor of the residual loop on synthetic tosses (ground truth read here only).

The tosses of ``benchmarks/residuals.py synthetic`` (20 cube tosses, 148 Hz, 0.15 mm / 2.9 mrad pose noise, one
hidden effect) are re-simulated noise-free with the true states recorded at every frame. On the loop's own blocks
(``loop.make_segments``, the benchmark's config) where the effect acts, the block error of that effect's component
(docs/residuals.md §1) is computed for the model without the effect ("before") and with the effect at its true
value ("after", the floor), from start states and against poses mixed from estimate and truth:

    start state  est    the loop's start state (``loop.start_state``, quadratic over ``init_fit_frames``)
                 Xtrue  est with the true start pose
                 vtrue  est with the true linear velocity
                 wtrue  est with the true angular velocity
                 true   the true start state
    compared to  obs    the noisy tracked poses (what the loop compares)
                 clean  the noise-free poses

``true`` against ``clean`` is the simulator/time-step mismatch (the rollout is the loop's simulator with the config's
settings, ``simulate.simulator_for``, from the same state; the tosses are generated at the generator's contact breaking
threshold, 1 mm); ``true`` against ``obs`` the pose noise of the compared frames; the rows between split the
start-state part. The figures of docs/residuals-findings.md "The floor the right model keeps" were made with the rollouts at
Bullet's 0.02 m, before the loop's default became 1 mm: ``--config '{"contact_breaking_m": null}'`` replays so.

    python benchmarks/residuals_floor.py --seeds 39 40 [--cases angular_damping restitution ...]
        [--config '{"init_fit_frames_flight": 41}']   (ResidualConfig fields: the loop's start state to diagnose)

(The per-model flight start, ``flight_start_model``, that the third command of the findings' AC ran with, was removed from the
loop after it was measured: docs/residuals-findings.md, "The floor the right model keeps".)
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

CASES = {"gravity_scale": {"gravity_scale": 0.95}, "restitution": {"restitution": 0.5},
         "linear_damping": {"linear_damping": 1.5}, "angular_damping": {"angular_damping": 2.0}}


class _Recorder:
    """Proxy of the pybullet module that records the base velocity read after every frame of a rollout."""

    def __init__(self, p):
        self._p = p
        self.last_step = False
        self.vel: list = []

    def __getattr__(self, name):
        f = getattr(self._p, name)
        if name == "stepSimulation":
            def step(*a, **k):
                self.last_step = True
                return f(*a, **k)
            return step
        if name == "getBasePositionAndOrientation":
            def pose(body, **k):
                if self.last_step:
                    v, w = self._p.getBaseVelocity(body, **k)
                    self.vel.append((np.array(v), np.array(w)))
                self.last_step = False
                return f(body, **k)
            return pose
        if name == "getBaseVelocity":
            self.last_step = False
        return f


def true_tosses(model, hidden, n, seed, noise_m, fps=148.0, duration=0.7):
    """The benchmark's tosses (``tests.residuals.lab.simulate_tosses``, same noise draws) and, per toss, the clean
    poses (T,4,4), world linear velocities (T,3) and body angular velocities (T,3) of the CoM (cube: CoM = origin)."""
    from service.residuals.simulate import BulletSimulator
    from service.residuals.types import ObservedTrajectory, SimRequest
    from service.transforms import so3_exp
    from tests.residuals.lab import SIDE, TOSS_CONTACT_BREAKING_M, toss_starts

    rng = np.random.default_rng(seed + 1000)
    t = np.arange(int(duration * fps)) / fps
    sim = BulletSimulator(0.002, contact_breaking_m=TOSS_CONTACT_BREAKING_M)
    rec = _Recorder(sim._p)
    sim._p = rec
    obs, truth = [], []
    try:
        for X0, v0, w0 in toss_starts(n, seed):
            rec.vel = []
            X = sim(SimRequest(model, X0, v0, w0, t, 0.0, None, dict(hidden)))
            V = np.array([v0] + [v for v, _ in rec.vel])
            W = np.array([X0[:3, :3].T @ (X0[:3, :3] @ w0)] + [X[k + 1, :3, :3].T @ w for k, (_, w) in enumerate(rec.vel)])
            Xn = X.copy()
            Xn[:, :3, 3] += rng.normal(scale=noise_m, size=(len(t), 3))
            Xn[:, :3, :3] = so3_exp(rng.normal(scale=noise_m / (SIDE / 2), size=(len(t), 3))) @ Xn[:, :3, :3]
            obs.append(ObservedTrajectory(t=t, X_WO=Xn))
            truth.append((X, V, W))
    finally:
        sim._p = rec._p
        sim.close()
    return tuple(obs), truth


def diagnose(case: str, seed: int, cfg, start_state=None) -> dict:
    from service.residuals.effects import REGISTRY, apply_effects
    from service.residuals.loop import Evaluator, effect_mask, make_segments, reduce_blocks
    from service.residuals.modes import classify, object_radius
    from service.residuals.simulate import simulator_for
    from service.residuals.types import ResidualInputs
    from service.transforms import rotation_angle
    from tests.residuals.lab import cube_model

    hidden = CASES[case]
    eff = REGISTRY[case]
    model = cube_model()
    obs, truth = true_tosses(model, hidden, 20, seed, 1.5e-4)
    inp = ResidualInputs(model, obs, 0.0)
    modes = [classify(model, tr, 0.0, None, cfg) for tr in obs]
    segs = make_segments(inp, modes, cfg)
    segs = [s for s in segs if effect_mask(s, eff).sum() >= 3]
    masks = [effect_mask(s, eff) for s in segs]
    theta = (hidden[case],)
    m1, e1 = apply_effects(model, {case: theta})
    variants = {}
    for s in segs:
        X, V, W = truth[s.traj]
        variants.setdefault("est", []).append(s)
        variants.setdefault("Xtrue", []).append(dataclasses.replace(s, X0=X[s.start]))
        variants.setdefault("vtrue", []).append(dataclasses.replace(s, v0=V[s.start]))
        variants.setdefault("wtrue", []).append(dataclasses.replace(s, w0=W[s.start]))
        variants.setdefault("true", []).append(dataclasses.replace(s, X0=X[s.start], v0=V[s.start], w0=W[s.start]))
    clean = {name: [dataclasses.replace(s, X_obs=truth[s.traj][0][s.start:s.stop]) for s in ss] for name, ss in variants.items()}
    from service.residuals.types import MODES

    m0 = np.array([s.mode[0] for s in segs])
    groups = {"flight": m0 == MODES.index("free_flight"), "contact": (m0 != MODES.index("free_flight")) & (m0 != MODES.index("rest")),
              "rest": m0 == MODES.index("rest")}
    sim = simulator_for(cfg)
    out = {"blocks": len(segs), "groups": {g: int(m.sum()) for g, m in groups.items()}}
    try:
        ev = Evaluator(sim, 0.0, object_radius(model))
        for name, ss in variants.items():
            for label, mod, ef in (("before", model, {}), ("after", m1, e1)):
                sims = [ev.rollout(mod, ef, sg) for sg in ss]  # one rollout, compared with both pose sets
                for against, table in (("obs", variants), ("clean", clean)):
                    fr = []
                    for Xs, sg in zip(sims, table[name]):
                        pos = np.linalg.norm(Xs[:, :3, 3] - sg.X_obs[:, :3, 3], axis=1)
                        rot = rotation_angle(np.swapaxes(sg.X_obs[:, :3, :3], 1, 2) @ Xs[:, :3, :3])
                        fr.append(np.stack([pos, ev.rot_scale * rot], 1))
                    row = {c: float(np.nanmean(reduce_blocks(fr, masks, c))) for c in ("position", "rotation", "both")}
                    out[(against, name, label)] = row
                    for g, gm in groups.items():  # by the mode of the block's start frame
                        if gm.any():
                            out[(against, name, label, g)] = {
                                c: float(np.nanmean(reduce_blocks(fr, masks, c)[gm])) for c in ("position", "rotation", "both")}
        # start-state errors of the loop's estimate (rms over blocks where the effect acts)
        dX = [np.linalg.norm(s.X0[:3, 3] - truth[s.traj][0][s.start, :3, 3]) for s in segs]
        dR = [float(rotation_angle(s.X0[:3, :3].T @ truth[s.traj][0][s.start, :3, :3])) for s in segs]
        dv = [np.linalg.norm(s.v0 - truth[s.traj][1][s.start]) for s in segs]
        dw = [np.linalg.norm(s.w0 - truth[s.traj][2][s.start]) for s in segs]
        out["start"] = {"pos_mm": 1e3 * float(np.sqrt(np.mean(np.square(dX)))), "rot_mrad": 1e3 * float(np.sqrt(np.mean(np.square(dR)))),
                        "v_mm_s": 1e3 * float(np.sqrt(np.mean(np.square(dv)))), "w_rad_s": float(np.sqrt(np.mean(np.square(dw))))}
    finally:
        sim.close()
    return out


def main() -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from service.residuals.types import ResidualConfig

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[39, 40])
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    ap.add_argument("--config", default="{}", help="JSON overrides of the benchmark's ResidualConfig")
    args = ap.parse_args()
    from _overrides import stage_overrides

    fixed = {"max_train_segments": 12, "fit_maxiter": 24, "folds": 2}
    over = stage_overrides(ap, args.config, "--config", "residuals")  # JSON of valid ResidualConfig fields
    if set(over) & set(fixed):
        ap.error(f"--config: set by this script, not by --config: {', '.join(sorted(set(over) & set(fixed)))}")
    cfg = dataclasses.replace(ResidualConfig.fast(), **fixed, **over)
    print("command:", " ".join(["python", *sys.argv]))
    for case in args.cases:
        comp = __import__("service.residuals.effects", fromlist=["REGISTRY"]).REGISTRY[case].component
        for seed in args.seeds:
            d = diagnose(case, seed, cfg)
            st = d["start"]
            print(f"{case} seed {seed}: {d['blocks']} blocks where it acts; component {comp}; start-state rms errors (true model) "
                  f"pos {st['pos_mm']:.3f} mm, rot {st['rot_mrad']:.2f} mrad, v {st['v_mm_s']:.1f} mm/s, w {st['w_rad_s']:.3f} rad/s")
            for against in ("obs", "clean"):
                for name in ("est", "Xtrue", "vtrue", "wtrue", "true"):
                    b, a = d[(against, name, "before")], d[(against, name, "after")]
                    print(f"   vs {against:5s} start {name:6s}: before/after(true effect) mm  "
                          + "  ".join(f"{c} {b[c] * 1e3:.3f}/{a[c] * 1e3:.3f} ({a[c] / b[c]:.2f})" for c in ("position", "rotation", "both")),
                          flush=True)
            for g, ng in d["groups"].items():
                if not ng:
                    continue
                print(f"   blocks starting in {g} ({ng}): " + "; ".join(
                    f"{against} {name} {d[(against, name, 'before', g)][comp] * 1e3:.3f}/{d[(against, name, 'after', g)][comp] * 1e3:.3f}"
                    for against in ("obs", "clean") for name in ("est", "Xtrue", "vtrue", "wtrue", "true")), flush=True)


if __name__ == "__main__":
    main()
