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
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from residuals import LEARNED_ERRORS  # noqa: E402
from residuals_corrected_split import parse_cell, unflat  # noqa: E402
from service.residuals.crossfit import held_out_parts, nuisance_blocks  # noqa: E402
from service.residuals.effects import REGISTRY, apply_effects  # noqa: E402

# the corrections that undo LEARNED_ERRORS: each size / 1.06, inertia / 1.3, the CoM shifted back, the table as it is
RIGHT = {"geometry_scale": (1 / LEARNED_ERRORS["scale"],) * 3, "inertia_scale": (1 / LEARNED_ERRORS["inertia_factor"],),
         "com_offset": tuple(-v for v in LEARNED_ERRORS["com_shift"]), "table_offset": (0.0,)}


def main() -> None:
    c = parse_cell(__doc__.splitlines()[0])
    name, th_true = c.name, c.theta
    th_null = REGISTRY[name].null
    parts, _units = held_out_parts(c.segs, 1, c.cfg)

    def E(corr, th, segs_):
        m, s = apply_effects(c.learned, {**corr, name: th})
        return float(np.nanmean(c.ev.errors(m, s, segs_))) * 1e3

    try:
        for f, (train, held) in enumerate(parts):
            tr_n = nuisance_blocks(train, f, c.cfg)
            base = unflat(c.out.by_mode["nuisance"]["folds"][f]["corrections"])
            fdc = c.out.by_mode["folds"][f]
            joint = unflat(fdc["corrections"])
            th_f = tuple(fdc["effects"].get(p, np.nan) for p in REGISTRY[name].params)
            rows = [("no-effect corrections, no effect", base, th_null), ("no-effect corrections, true effect", base, th_true),
                    (f"fold's joint point {th_f}", joint, th_f), ("joint corrections, true effect", joint, th_true),
                    ("right corrections, no effect", RIGHT, th_null), ("right corrections, true effect", RIGHT, th_true),
                    ("no change, true effect", {}, th_true)]
            print(f"{c.case} {c.cfg.seed} fold {f + 1}: train {len(tr_n)} blocks, held {len(held)}", flush=True)
            for lab, corr, th in rows:
                if not np.all(np.isfinite(th)):
                    continue
                print(f"   {lab:45s} train {E(corr, th, tr_n):6.3f} mm  all {len(train)} training blocks "
                      f"{E(corr, th, train):6.3f} mm  held-out {E(corr, th, held):6.3f} mm", flush=True)
    finally:
        c.sim.close()


if __name__ == "__main__":
    main()
