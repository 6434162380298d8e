"""Diagnosis (docs/residuals-findings.md, "Each hypothesis with its own corrections"): is the point the joint refit
(corrections + candidate) ends at the minimum of its training objective, or is the right point (the corrections that
undo the benchmark's learned-model errors, with the hidden effect at its true value) lower, so that a better start
would find it? On one cell of ``benchmarks/residuals.py strike --learned-model`` (same session, model, settings and
folds), each fold's mean error over all frames at several (corrections, effect) points: on the nuisance fit's
training blocks (``max_nuisance_segments`` of them, the objective), on all the fold's training blocks, and on its
held-out blocks. Ground truth is read here only.

    python benchmarks/residuals.py strike --learned-model --folds 2 --seeds 807 --cases clock_offset --save-outputs DIR
    python benchmarks/residuals_nuisance_points.py clock_offset 807 DIR/clock_offset_807.pkl
"""
import dataclasses
import pickle
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from residuals import STRIKE_CASES  # noqa: E402
from service.residuals import loop as L  # noqa: E402
from service.residuals.crossfit import held_out_parts  # noqa: E402
from service.residuals.effects import NUISANCE_LEARNED, REGISTRY, apply_effects  # noqa: E402
from service.residuals.modes import classify  # noqa: E402
from service.residuals.simulate import simulator_for  # noqa: E402
from service.residuals.types import ResidualConfig, ResidualInputs  # noqa: E402
from service.synth.types import HiddenEffects, SynthSpec  # noqa: E402
from tests.residuals.synthlab import lab_session, perturbed_model  # noqa: E402
from residuals_corrected_split import unflat  # noqa: E402

case, seed, pk = sys.argv[1], int(sys.argv[2]), sys.argv[3]
hidden, name, _key, truth, cands = STRIKE_CASES[case]
ls = lab_session(SynthSpec(object="baking_box", interaction="strike", seed=seed, preset="tiny", n_frames=900,
                           friction_object_table=0.15, effects=HiddenEffects(**hidden)), pose_noise_m=5e-4, pose_noise_rad=5e-3)
cfg = dataclasses.replace(ResidualConfig.fast(), candidates=cands, segment_s=0.3, seed=seed, fit_maxiter=24,
                          max_train_segments=10, nuisance=NUISANCE_LEARNED, nuisance_maxiter=70, folds=2)
learned = perturbed_model(ls, scale=1.06, inertia_factor=1.3, com_shift=(0.004, -0.003, 0.0))
out = pickle.load(open(pk, 'rb'))
robot = L.smooth_robot(ls.robot, cfg)
inp = ResidualInputs(learned, (ls.trajectory,), ls.table_height, robot=(robot,))
segs = L.make_segments(inp, [classify(learned, ls.trajectory, ls.table_height, robot, cfg)], cfg)
parts, units = held_out_parts(segs, 1, cfg)
sim = simulator_for(cfg)
ev = L.Evaluator(sim, ls.table_height, out.by_mode["rot_scale_m"])
th_true = tuple(truth) if isinstance(truth, tuple) else (truth,)
th_null = REGISTRY[name].null
right = {"geometry_scale": (1 / 1.06,) * 3, "inertia_scale": (1 / 1.3,), "com_offset": (-0.004, 0.003, 0.0), "table_offset": (0.0,)}
fitted = dict(out.effects)
for f, (train, held) in enumerate(parts):
    tr_n = list(train)
    if len(tr_n) > cfg.max_nuisance_segments:
        sub = np.random.default_rng(cfg.seed + 99 + 1000 * f).choice(len(tr_n), cfg.max_nuisance_segments, replace=False)
        tr_n = [tr_n[i] for i in sorted(sub)]
    base = unflat(out.by_mode["nuisance"]["folds"][f]["corrections"])
    fdc = out.by_mode["folds"][f]
    joint = unflat(fdc["corrections"]); th_f = tuple(fdc["effects"].get(p, np.nan) for p in REGISTRY[name].params)
    def E(corr, th, segs_):
        m, s = apply_effects(learned, {**corr, name: th})
        return float(np.nanmean(ev.errors(m, s, segs_))) * 1e3
    rows = [("no-effect corrections, no effect", base, th_null), ("no-effect corrections, true effect", base, th_true),
            (f"fold's joint point {th_f}", joint, th_f), ("joint corrections, true effect", joint, th_true),
            ("right corrections, no effect", right, th_null), ("right corrections, true effect", right, th_true),
            ("no change, true effect", {}, th_true)]
    print(f"{case} {seed} fold {f + 1}: train {len(tr_n)} blocks, held {len(held)}", flush=True)
    for lab, c, th in rows:
        if not np.all(np.isfinite(th)):
            continue
        print(f"   {lab:45s} train {E(c, th, tr_n):6.3f} mm  all {len(train)} training blocks {E(c, th, train):6.3f} mm  held-out {E(c, th, held):6.3f} mm", flush=True)
sim.close()
