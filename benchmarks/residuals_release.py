"""Release blocks (docs/residuals-findings.md, "Release blocks"): what a slide effect at its true value shows on the
slide alone, against the launch blocks it is judged on.

For strike sessions of the synthetic lab with one hidden effect, on every launch block (``loop.make_segments``) and its
release block (``loop.release_segment``: from N frames after the last robot-contact frame to the block's end, started
from the tracked state there), the error where the effect acts (its component on its frames, ``loop.acting_errors``)
of the declared model and of the model with the effect at its true value (no fit, no held-out test: what the data can
show). With ``--learned-model`` the model carries the benchmark's learned-model errors (no corrections), and
``--value`` sets the effect's value instead of the truth (e.g. a false damping on a plain session).

    python benchmarks/residuals_release.py --seeds 751 752 --case linear_damping [--gap 2] [--learned-model] [--degree 3]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def blocks_line(ev, model, m1, e1, segs, eff, all_frames=False) -> tuple[str, np.ndarray, np.ndarray]:
    """The error where ``eff`` acts per block (blocks with >= 3 of its frames), declared model against ``m1``:
    its component on its frames (``loop.acting_errors``), or with ``all_frames`` on every tracked frame of the block
    (``loop.reduce_blocks``, as rule 10 reads release blocks); (text, before, after), m."""
    from service.residuals.loop import _acts_on, acting_errors, reduce_blocks

    segs = [s for s in segs if _acts_on(s, eff)]
    if not segs:
        return "no block", np.zeros(0), np.zeros(0)
    if all_frames:
        b = reduce_blocks(ev.frame_split(model, dict(model.effects), segs), component=eff.component)
        a = reduce_blocks(ev.frame_split(m1, {**model.effects, **e1}, segs), component=eff.component)
    else:
        b = acting_errors(ev.frame_split(model, dict(model.effects), segs), segs, eff)
        a = acting_errors(ev.frame_split(m1, {**model.effects, **e1}, segs), segs, eff)
    d = b - a
    txt = (f"{len(segs):2d} blocks, {np.mean(b) * 1e3:6.2f} -> {np.mean(a) * 1e3:6.2f} mm "
           f"({(np.mean(b) - np.mean(a)) / np.mean(b):+.0%}), better/worse {int(np.sum(d > 0))}/{int(np.sum(d < 0))}")
    return txt, b, a


def main() -> None:
    from residuals import LEARNED_ERRORS, STRIKE_CASES

    from service.residuals.effects import REGISTRY, apply_effects
    from service.residuals.loop import Evaluator, make_segments, release_segment, smooth_robot
    from service.residuals.modes import classify, object_radius
    from service.residuals.simulate import simulator_for
    from service.residuals.types import ResidualConfig, ResidualInputs
    from service.synth.types import HiddenEffects, SynthSpec
    from tests.residuals.synthlab import lab_session, perturbed_model

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", required=True)
    ap.add_argument("--case", default="linear_damping", choices=sorted(STRIKE_CASES))
    ap.add_argument("--effect", default=None, help="the effect compared (default: the case's)")
    ap.add_argument("--value", type=float, nargs="+", default=None, help="its value (default: the case's truth)")
    ap.add_argument("--gap", type=int, default=2, help="release block from this many frames after the last robot contact")
    ap.add_argument("--learned-model", action="store_true")
    ap.add_argument("--degree", type=int, choices=(2, 3), default=2,
                    help="the release blocks' start-state polynomial (rule 10's release_blocks_degree; 3: cubic)")
    args = ap.parse_args()
    hidden, name, _key, truth, _c = STRIKE_CASES[args.case]
    name = args.effect or name
    if name is None:
        ap.error(f"--case {args.case}: no hidden effect to compare; give --effect and --value")
    if name not in REGISTRY:
        ap.error(f"--effect: unknown effect {name!r}; known: {sorted(REGISTRY)}")
    eff = REGISTRY[name]
    if args.value is None and truth is None:
        ap.error(f"--case {args.case} has no true value of {name}; give --value")
    theta = tuple(args.value) if args.value else (tuple(truth) if isinstance(truth, tuple) else (truth,))
    if len(theta) != len(eff.null):
        ap.error(f"--value: {name} takes {len(eff.null)} number(s), not {len(theta)} ({theta})")
    if args.gap < 0:
        ap.error(f"--gap: frames after the release, an integer >= 0, not {args.gap}")
    cfg = dataclasses.replace(ResidualConfig.fast(), segment_s=0.3)
    tot = {"launch": [[], []], "release": [[], []]}
    for seed in args.seeds:
        ls = lab_session(SynthSpec(object="baking_box", interaction="strike", seed=seed, preset="tiny", n_frames=900,
                                   friction_object_table=0.15,
                                   effects=HiddenEffects(**hidden)), pose_noise_m=0.0005, pose_noise_rad=0.005)
        model = perturbed_model(ls, **LEARNED_ERRORS) if args.learned_model else perturbed_model(ls)
        robot = smooth_robot(ls.robot, cfg)
        inp = ResidualInputs(model, (ls.trajectory,), ls.table_height, robot=(robot,))
        segs = make_segments(inp, [classify(model, ls.trajectory, ls.table_height, robot, cfg)], cfg)
        launch = [s for s in segs if s.launch]
        rel = [r for r in (release_segment(s, args.gap, cfg, args.degree) for s in launch) if r is not None]
        sim = simulator_for(cfg)
        try:
            ev = Evaluator(sim, ls.table_height, object_radius(model))
            m1, e1 = apply_effects(model, {name: theta})
            out = []
            for kind, ss in (("launch", launch), ("release", rel)):
                txt, b, a = blocks_line(ev, model, m1, e1, ss, eff, kind == "release")
                tot[kind][0].extend(b)
                tot[kind][1].extend(a)
                out.append(f"{kind} {txt}")
        finally:
            sim.close()
        slide = [len(r.t) for r in rel]
        print(f"seed {seed}: {name} {theta} against none ({eff.component}): " + "; ".join(out)
              + f"; release blocks' frames {slide}", flush=True)
    for kind, (b, a) in tot.items():
        b, a = np.array(b), np.array(a)
        if len(b):
            print(f"all {kind} blocks: {len(b)}, {b.mean() * 1e3:.2f} -> {a.mean() * 1e3:.2f} mm "
                  f"({(b.mean() - a.mean()) / b.mean():+.0%}), better/worse {int(np.sum(b > a))}/{int(np.sum(b < a))}")


if __name__ == "__main__":
    main()
