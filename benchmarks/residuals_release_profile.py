"""Is a slide effect's value fitted on release blocks biased? (docs/residuals-findings.md, "The reported value from
the slide alone", EN and EQ.)

For strike sessions of the synthetic lab with one hidden effect and the catalogue model (the object's true shape,
mass and inertia, the declared friction), the training objective of ``loop._fit`` (the mean scalar error on the
effect's frames, ``Evaluator.errors``) at a grid of values of the effect, on every launch block where it acts
(``loop.make_segments``) and on every release block (``loop.release_segment``, 1 frame after the release, started
from the tracked slide with a polynomial of ``--degree``): per session the grid value with the lowest mean, then over
all sessions the minimum of the parabola through the pooled means' best three grid values. No fit, no held-out test:
what the blocks themselves ask for. ``--noise 0``: poses without noise (the start state's noise removed).

    python benchmarks/residuals_release_profile.py --seeds 751 752 753 [--noise 0] [--degree 3]
    python benchmarks/residuals_release_profile.py --seeds 751 752 --case friction --effect friction_table \\
        --grid 0.2 0.25 0.28 0.3 0.32 0.35 0.4
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def profile(seed: int, case: str, effect: str, grid: list[float], noise: float, degree: int) -> dict[str, np.ndarray]:
    """{"launch": (G, S), "release": (G, S)}: the error at each grid value (rows) on each block (columns)."""
    from residuals import STRIKE_CASES
    from service.residuals.effects import REGISTRY, apply_effects
    from service.residuals.loop import Evaluator, _acts_on, effect_mask, make_segments, release_segment, smooth_robot
    from service.residuals.modes import classify, object_radius
    from service.residuals.simulate import simulator_for
    from service.residuals.types import ResidualConfig, ResidualInputs
    from service.synth.types import HiddenEffects, SynthSpec
    from tests.residuals.synthlab import lab_session, perturbed_model

    eff = REGISTRY[effect]
    cfg = dataclasses.replace(ResidualConfig.fast(), segment_s=0.3)
    ls = lab_session(SynthSpec(object="baking_box", interaction="strike", seed=seed, preset="tiny", n_frames=900,
                               friction_object_table=0.15, effects=HiddenEffects(**STRIKE_CASES[case][0])),
                     pose_noise_m=noise, pose_noise_rad=10 * noise)
    model = perturbed_model(ls)
    robot = smooth_robot(ls.robot, cfg)
    inp = ResidualInputs(model, (ls.trajectory,), ls.table_height, robot=(robot,))
    segs = make_segments(inp, [classify(model, ls.trajectory, ls.table_height, robot, cfg)], cfg)
    launch = [s for s in segs if s.launch and _acts_on(s, eff)]
    rel = [r for r in (release_segment(s, 1, cfg, degree) for s in launch) if r is not None and _acts_on(r, eff)]
    sim = simulator_for(cfg)
    try:
        ev = Evaluator(sim, ls.table_height, object_radius(model))
        out = {}
        for kind, blocks in (("launch", launch), ("release", rel)):
            masks = [effect_mask(s, eff) for s in blocks]
            rows = []
            for v in grid:
                m1, e1 = apply_effects(model, {effect: (v,)})
                rows.append(ev.errors(m1, {**model.effects, **e1}, blocks, masks))
            out[kind] = np.array(rows, float).reshape(len(grid), len(blocks))
        return out
    finally:
        sim.close()


def parabola_min(grid: np.ndarray, m: np.ndarray) -> float:
    """The minimum of the parabola through the best grid value and its two neighbours (the grid's end: the end three)."""
    i = int(np.clip(np.argmin(m), 1, len(m) - 2))
    c = np.polyfit(grid[i - 1:i + 2], m[i - 1:i + 2], 2)
    return float(-c[1] / (2 * c[0])) if c[0] > 0 else float(grid[int(np.argmin(m))])


def main() -> None:
    from _env import library_versions
    from residuals import STRIKE_CASES

    from service.residuals.effects import SLIDE_EFFECTS

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", required=True)
    ap.add_argument("--case", default="linear_damping", help=f"the hidden effect, one of {sorted(STRIKE_CASES)}")
    ap.add_argument("--effect", default="linear_damping", help=f"the effect profiled, one of {list(SLIDE_EFFECTS)}")
    ap.add_argument("--grid", type=float, nargs="+", default=[1.0, 1.4, 1.7, 2.0, 2.3, 2.6, 3.0])
    ap.add_argument("--noise", type=float, default=0.0005, help="pose noise (m; rotation 10x in rad)")
    ap.add_argument("--degree", type=int, choices=(2, 3), default=2, help="the release start state's polynomial")
    a = ap.parse_args()
    if a.case not in STRIKE_CASES:
        ap.error(f"--case {a.case!r}: expected one of {sorted(STRIKE_CASES)}")
    if a.effect not in SLIDE_EFFECTS:
        ap.error(f"--effect {a.effect!r}: expected a slide effect, one of {list(SLIDE_EFFECTS)}")
    if len(a.grid) < 3 or sorted(set(a.grid)) != a.grid:
        ap.error("--grid: at least three increasing values")
    if a.noise < 0:
        ap.error(f"--noise {a.noise}: must be >= 0")
    print("command:", " ".join(["python", *sys.argv]))
    print("libraries:", library_versions())
    grid = np.array(a.grid, float)
    pooled: dict[str, list[np.ndarray]] = {"launch": [], "release": []}
    for seed in a.seeds:
        prof = profile(seed, a.case, a.effect, a.grid, a.noise, a.degree)
        parts = []
        for kind, E in prof.items():
            pooled[kind].append(E)
            m = E.mean(1) if E.shape[1] else np.full(len(grid), np.nan)
            best = f"{grid[int(np.nanargmin(m))]:g}" if E.shape[1] else "-"
            parts.append(f"{kind} {E.shape[1]} blocks, best {best}: " + " ".join(f"{x * 1e3:.2f}" for x in m))
        print(f"seed {seed}: " + "; ".join(parts), flush=True)
    for kind, Es in pooled.items():
        E = np.concatenate(Es, 1)
        if not E.shape[1]:
            print(f"all {kind}: no block")
            continue
        m = E.mean(1)
        print(f"all {kind}: {E.shape[1]} blocks, mean error (mm) by value "
              + ", ".join(f"{v:g}: {x * 1e3:.3f}" for v, x in zip(grid, m))
              + f"; parabolic minimum {parabola_min(grid, m):.2f}")


if __name__ == "__main__":
    main()
