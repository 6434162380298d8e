"""Diagnosis of the friction–damping look-alike on strikes (docs/residuals-findings.md, "Friction and damping told apart").

Runs the loop on synthetic-lab strike sessions (the strike benchmark's settings: catalogue model, 2 folds) and, for
every round in which both the table friction and the linear damping were fitted, compares their held-out fold
models block by block on several observables (no extra rollout: the round's own held-out frames):

- ``all``: the scalar error on all frames of the blocks where either acts (the measure of rule 9, a head-to-head on it,
  tried and removed: docs/residuals-findings.md, "Friction taken for damping");
- ``pos`` / ``rot``: its position part |Δp| and rotation part ρ·∠ alone, on the same frames;
- ``<mode>.pos`` / ``<mode>.rot``: restricted to the frames of one contact mode (sliding, robot_contact, rest).

The decisions of the loop are the ones without any look-alike rule (the hook of rule 9b, ``crossfit.lookalike_refutation``,
is replaced by a recorder that computes the rule's verdict and leaves the round as it is). Ground truth is read only to
name the case.

    python benchmarks/residuals_lookalike.py --seeds 741 742 --cases linear_damping friction [--sphere-drive inverse
        --robot-smooth-weights biweight --robot-smooth 0.08] [--save /tmp/x.pkl]
    python benchmarks/residuals_lookalike.py --load /tmp/x.pkl
"""

from __future__ import annotations

import argparse
import dataclasses
import pickle
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

OBS_MODES = ("sliding", "robot_contact", "rest")


def _record(store: list, refutation):
    """A stand-in for ``crossfit.lookalike_refutation`` (the rule itself: ``refutation``) that records the round and
    the rule's verdict and changes nothing."""

    def rule(round_res, folds, cfg, final, history, rnd):
        names = {r[2].effect: r for r in round_res}
        if "friction_table" in names and "linear_damping" in names:
            rec = {"round": rnd, "modes": [[sg.mode.copy() for sg in fd.held] for fd in folds],
                   "tracked": [[sg.tracked.copy() for sg in fd.held] for fd in folds],
                   "units": [fd.units.copy() for fd in folds],
                   "before": [list(fd.cur_frames) for fd in folds], "passes": {}, "theta": {}, "after": {}}
            for n in ("friction_table", "linear_damping"):
                ok, gain, cand, per, th = names[n]
                rec["passes"][n] = bool(ok)
                rec["theta"][n] = [tuple(p["theta"]) for p in per]
                rec["after"][n] = [list(p["after_frames"]) for p in per]
            refuted = refutation(round_res, folds, cfg, {}, [], rnd)  # rule 9b's verdict, not applied
            rec["refuted"] = [r[2].effect for r0, r in zip(round_res, refuted) if r0[0] and not r[0]]
            store.append(rec)
        return round_res

    return rule


def compare(rec: dict, cfg) -> dict[str, tuple]:
    """Per observable: (damping's mean block error, friction's, blocks where the damping is better, worse, sign
    test p, t lower bound of the damping's mean relative improvement over units), m."""
    from service.residuals.effects import REGISTRY
    from service.residuals.loop import Segment, head_to_head, sign_test, unit_improvements
    from service.residuals.types import MODES

    ef, ed = REGISTRY["friction_table"], REGISTRY["linear_damping"]
    mode_sets = {"all": None, **{m: (MODES.index(m),) for m in OBS_MODES}}
    out = {}
    for label, ms in mode_sets.items():
        for comp in ("both", "pos", "rot") if label == "all" else ("pos", "rot"):
            eb_f, eb_d, uu = [], [], []
            for f in range(len(rec["modes"])):
                for i, mode in enumerate(rec["modes"][f]):
                    m_f = np.isin(mode, [MODES.index(x) for x in ef.modes]) & rec["tracked"][f][i]
                    m_d = np.isin(mode, [MODES.index(x) for x in ed.modes]) & rec["tracked"][f][i]
                    if max(m_f.sum(), m_d.sum()) < 3:
                        continue
                    sel = rec["tracked"][f][i].copy() if ms is None else np.isin(mode, ms) & rec["tracked"][f][i]
                    if sel.sum() < 1:
                        continue
                    vals = []
                    for n in ("friction_table", "linear_damping"):
                        e = rec["after"][n][f][i]
                        x = e[:, 0] + e[:, 1] if comp == "both" else e[:, 0] if comp == "pos" else e[:, 1]
                        vals.append(float(np.nanmean(x[sel])))
                    eb_f.append(vals[0])
                    eb_d.append(vals[1])
                    uu.append(rec["units"][f][i])
            ef_, ed_, u = np.array(eb_f), np.array(eb_d), np.array(uu)
            if len(ef_) < 2:
                continue
            n_pos, n_neg, p = sign_test(ef_, ed_, cfg)
            x = unit_improvements(ef_, ed_, u, "relative")
            from scipy.stats import t as student

            lb = float(x.mean() - student.ppf(0.95, len(x) - 1) * x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else np.nan
            ub = float(x.mean() + student.ppf(0.95, len(x) - 1) * x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else np.nan
            out[f"{label}.{comp}"] = (ed_.mean(), ef_.mean(), n_pos, n_neg, p, lb, ub, len(ef_))
    return out


def main() -> None:
    from _overrides import nonnegative_float, positive_int
    from residuals import STRIKE_CASES

    from service.residuals.types import ROBOT_SMOOTH_WEIGHTS, SPHERE_DRIVES

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[741])
    ap.add_argument("--cases", nargs="+", default=["linear_damping", "friction"], choices=sorted(STRIKE_CASES))
    ap.add_argument("--sphere-drive", default=None, choices=SPHERE_DRIVES)
    ap.add_argument("--robot-smooth-weights", default=None, choices=ROBOT_SMOOTH_WEIGHTS)
    ap.add_argument("--robot-smooth", type=nonnegative_float, default=None)
    ap.add_argument("--folds", type=positive_int, default=2)
    ap.add_argument("--save", default=None)
    ap.add_argument("--load", default=None)
    args = ap.parse_args()
    if args.load and not Path(args.load).is_file():
        ap.error(f"--load: no such file {args.load}")

    from service.residuals import crossfit as cf
    from service.residuals import run
    from service.residuals.types import ResidualConfig, ResidualInputs
    from service.synth.types import HiddenEffects, SynthSpec
    from tests.residuals.synthlab import lab_session, perturbed_model

    results = []
    if args.load:
        results = pickle.load(open(args.load, "rb"))
    else:
        for case in args.cases:
            hidden, name, key, truth, cands = STRIKE_CASES[case]
            for seed in args.seeds:
                ls = lab_session(SynthSpec(object="baking_box", interaction="strike", seed=seed, preset="tiny",
                                           n_frames=900, friction_object_table=0.15, effects=HiddenEffects(**hidden)),
                                 pose_noise_m=5e-4, pose_noise_rad=5e-3)
                path = {k: v for k, v in (("sphere_drive", args.sphere_drive),
                                          ("robot_smooth_weights", args.robot_smooth_weights),
                                          ("robot_smooth_s", args.robot_smooth)) if v is not None}
                cfg = dataclasses.replace(ResidualConfig.fast(), candidates=cands, segment_s=0.3, seed=seed,
                                          fit_maxiter=24, max_train_segments=10, nuisance=(), nuisance_maxiter=70,
                                          folds=args.folds, lookalike_refute=True, **path)
                store: list = []
                orig = cf.lookalike_refutation
                cf.lookalike_refutation = _record(store, orig)
                try:
                    out = run(ResidualInputs(perturbed_model(ls), (ls.trajectory,), ls.table_height, robot=(ls.robot,)), cfg)
                finally:
                    cf.lookalike_refutation = orig
                results.append({"case": case, "seed": seed, "accepted": list(out.accepted), "effects": dict(out.effects),
                                "recs": store, "cfg": cfg})
                print(f"{case} {seed}: accepted {list(out.accepted)} {out.effects}", flush=True)
        if args.save:
            pickle.dump(results, open(args.save, "wb"))
    for r in results:
        for rec in r["recs"]:
            th = {n: ", ".join(f"{t[0]:.3g}" for t in v) for n, v in rec["theta"].items()}
            print(f"\n{r['case']} {r['seed']} round {rec['round'] + 1} (accepted {r['accepted']}); passes "
                  f"{rec['passes']}; refuted by rule 9b {rec.get('refuted')}; folds: friction {th['friction_table']}, damping {th['linear_damping']}")
            print("  observable          damping  friction (mm)  damp better/worse  p      rel.impr. lower..upper  n")
            for k, (d, f, npos, nneg, p, lb, ub, n) in compare(rec, r["cfg"]).items():
                print(f"  {k:20s} {d * 1e3:7.3f} {f * 1e3:7.3f}        {npos:3d}/{nneg:<3d}         {p:.3f}  "
                      f"{lb:+.3f} .. {ub:+.3f}  {n}")


if __name__ == "__main__":
    main()
