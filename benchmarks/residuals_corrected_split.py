"""Diagnosis (docs/residuals-findings.md, "Learned-model strikes: restitution, angular damping, clock offset and
object-robot friction"): how much a hidden effect shows through the learned model's corrections. On one cell of
``benchmarks/residuals.py strike --learned-model`` (the same session, model and settings), the error where the effect
acts (its component, on its frames of every block where it acts; the loop's own blocks, start states and simulator)
with the effect at "no effect" and at its *true* value, for the true model (the catalogue shape, no learned errors),
the learned model as given, and each fold's corrected learned model (the nuisance corrections the loop fitted before
judging any effect, read from the cell's pickled loop output). Ground truth is read here only.

    python benchmarks/residuals.py strike --learned-model --folds 2 --seeds 807 --cases restitution --save-outputs DIR
    python benchmarks/residuals_corrected_split.py restitution 807 DIR/restitution_807.pkl
"""
import argparse
import dataclasses
import pickle
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from residuals import LEARNED_ERRORS, STRIKE_CASES  # noqa: E402
from service.residuals import loop as L  # noqa: E402
from service.residuals.effects import NUISANCE_LEARNED, REGISTRY, apply_effects  # noqa: E402
from service.residuals.modes import classify  # noqa: E402
from service.residuals.simulate import simulator_for  # noqa: E402
from service.residuals.types import ResidualConfig, ResidualInputs  # noqa: E402
from service.synth.types import HiddenEffects, SynthSpec  # noqa: E402
from tests.residuals.synthlab import lab_session, perturbed_model  # noqa: E402


def unflat(c: dict[str, float]) -> dict[str, tuple]:
    """Flat correction keys (geometry_scale_1, ..., table_offset) -> {correction name: θ}."""
    out = {}
    for n in NUISANCE_LEARNED:
        ps = REGISTRY[n].params
        if any(p in c for p in ps):
            out[n] = tuple(c.get(p, REGISTRY[n].null[i]) for i, p in enumerate(ps))
    return out


@dataclass
class Cell:
    """One learned-model strike cell as ``benchmarks/residuals.py strike --learned-model`` runs it, with the loop's
    pickled output: the case, the lab session ``ls``, the config, the learned model, the output, the smoothed robot path, the
    loop's blocks and an evaluator on the loop's simulator (close ``sim`` after use); ``name`` and ``theta`` the hidden
    effect and its true value (ground truth)."""
    case: str
    ls: object
    cfg: ResidualConfig
    learned: object
    out: object
    robot: object
    segs: list
    sim: object
    ev: object
    name: str
    theta: tuple


def parse_cell(description: str) -> Cell:
    """The command line ``CASE SEED PICKLE`` of a diagnosis script, checked (a case of ``STRIKE_CASES`` with a hidden
    effect, an integer seed, a readable pickle of that cell's loop output), and the cell it names."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("case", choices=[c for c, v in STRIKE_CASES.items() if v[1]], help="the strike case (hidden effect)")
    ap.add_argument("seed", type=int, help="the strike session's seed")
    ap.add_argument("pickle", type=Path, help="the cell's loop output (benchmarks/residuals.py strike --save-outputs)")
    args = ap.parse_args()
    if not args.pickle.is_file():
        ap.error(f"pickle: no such file: {args.pickle} (make it with benchmarks/residuals.py strike --learned-model "
                 f"--folds 2 --seeds {args.seed} --cases {args.case} --save-outputs DIR)")
    hidden, name, _key, truth, cands = STRIKE_CASES[args.case]
    ls = lab_session(SynthSpec(object="baking_box", interaction="strike", seed=args.seed, preset="tiny", n_frames=900,
                               friction_object_table=0.15, effects=HiddenEffects(**hidden)),
                     pose_noise_m=5e-4, pose_noise_rad=5e-3)
    cfg = dataclasses.replace(ResidualConfig.fast(), candidates=cands, segment_s=0.3, seed=args.seed, fit_maxiter=24,
                              max_train_segments=10, nuisance=NUISANCE_LEARNED, nuisance_maxiter=70, folds=2)
    learned = perturbed_model(ls, **LEARNED_ERRORS)
    with open(args.pickle, "rb") as fh:
        out = pickle.load(fh)
    robot = L.smooth_robot(ls.robot, cfg)
    inp = ResidualInputs(learned, (ls.trajectory,), ls.table_height, robot=(robot,))
    segs = L.make_segments(inp, [classify(learned, ls.trajectory, ls.table_height, robot, cfg)], cfg)
    sim = simulator_for(cfg)
    ev = L.Evaluator(sim, ls.table_height, out.by_mode["rot_scale_m"])
    theta = tuple(truth) if isinstance(truth, tuple) else (truth,)
    return Cell(args.case, ls, cfg, learned, out, robot, segs, sim, ev, name, theta)


def main() -> None:
    c = parse_cell(__doc__.splitlines()[0])
    ls, cfg, robot, ev, name, theta = c.ls, c.cfg, c.robot, c.ev, c.name, c.theta
    eff = REGISTRY[name]

    def split(model, base_eff: dict, th_off: float, label: str) -> None:
        """Error where the effect acts, no effect -> true value, on the blocks where it acts (modes re-classified
        with ``model`` and the table offset ``th_off``, as the loop does for a corrected model)."""
        mode = classify(model, ls.trajectory, ls.table_height + th_off, robot, cfg)
        segs = [dataclasses.replace(sg, mode=mode[sg.start:sg.stop]) for sg in c.segs]
        masks = [L.effect_mask(sg, eff) for sg in segs]
        keep = [i for i, m in enumerate(masks) if m.sum() >= 3]
        segs, masks = [segs[i] for i in keep], [masks[i] for i in keep]
        m1, e1 = apply_effects(model, {name: theta})
        b = L.reduce_blocks([L.frame_component(f, eff.component) for f in ev.frame_split(model, dict(base_eff), segs)], masks)
        a = L.reduce_blocks([L.frame_component(f, eff.component) for f in ev.frame_split(m1, {**base_eff, **e1}, segs)], masks)
        d = b - a
        print(f"  {label}: {len(segs)} blocks where it acts; {eff.component} {np.nanmean(b) * 1e3:.2f} -> "
              f"{np.nanmean(a) * 1e3:.2f} mm ({np.nanmean(a) / np.nanmean(b):.3f}x), better/worse "
              f"{int(np.sum(d > 0))}/{int(np.sum(d < 0))}", flush=True)

    try:
        print(f"{c.case} {cfg.seed}: {name} at its true value {theta} against no effect")
        split(perturbed_model(ls), {}, 0.0, "true model")
        split(c.learned, {}, 0.0, "learned model, uncorrected")
        for f, fd in enumerate(c.out.by_mode["nuisance"]["folds"]):
            m, e = apply_effects(c.learned, unflat(fd.get("corrections", {})))
            split(m, e, float(e.get("table_offset", 0.0)), f"fold {f + 1} corrected")
    finally:
        c.sim.close()


if __name__ == "__main__":
    main()
