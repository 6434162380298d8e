"""The residual loop on synthetic-lab sessions with hidden effects, through the whole pipeline.

Each session is generated with one hidden effect (written only to the sidecar, never told to the service),
processed by the same flow as the API (tracking -> contact -> fusion -> evaluation -> residuals), and the
report's residual block is compared with the sidecar's truth. Prints one row per session: the accepted
effects and fitted values against the truth, the nuisance corrections of the learned model, the held-out
error (all frames) of the learned model -> corrected model -> corrected model + accepted effects, and the
error of the true effect's candidate on its own held-out frames before -> after.

    python benchmarks/residuals_pipeline.py [--preset small] [--frames N] [--seed 21] [--object milk_carton]
        [--interaction push] [--cases none clock_offset ...] [--work DIR]

``--frames`` lengthens the recording (same resolution and frame rate as the preset): a 5 s session holds
one or two strokes, too few held-out blocks in robot contact for any test.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import time
from pathlib import Path

CASES = {
    "none": {},
    "friction_object_table": {"friction_object_table": 0.5},
    "clock_offset": {"clock_offset": 0.1},
    "table_tilt": {"table_tilt": (0.05, 0.0)},
    "linear_damping": {"linear_damping": 3.0},
    "restitution": {"restitution": 0.5},
}
# the loop's candidate that should explain each hidden effect, and its parameter key
EXPECTED = {
    "friction_object_table": ("friction_table", "friction_object_table"),
    "clock_offset": ("clock_offset", "clock_offset"),
    "table_tilt": ("table_tilt", "table_tilt_x"),
    "linear_damping": ("linear_damping", "linear_damping"),
    "restitution": ("restitution", "restitution"),
}


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    c = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime + c.ru_utime + c.ru_stime


def _mm(x) -> str:
    return "-" if x is None else f"{1e3 * x:.2f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="small")
    ap.add_argument("--frames", type=int, default=None, help="number of frames (default: the preset's)")
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--object", default="milk_carton")
    ap.add_argument("--interaction", default="push")
    ap.add_argument("--pipeline-preset", default="default")
    ap.add_argument("--cases", nargs="*", default=list(CASES))
    ap.add_argument("--work", default="/tmp/vysics-residuals-pipeline")
    a = ap.parse_args()
    work = Path(a.work)
    data_dir = work / "data"
    os.environ["VYSICS_DATA_DIR"] = str(data_dir)
    from service.synth import make_session
    from service.synth.types import HiddenEffects, SynthSpec
    from workers.cli import process

    frames = f" --frames {a.frames}" if a.frames else ""
    print(f"# python benchmarks/residuals_pipeline.py --preset {a.preset}{frames} --seed {a.seed} --object {a.object} "
          f"--interaction {a.interaction} --cases {' '.join(a.cases)}")
    print("case | true | accepted (fitted) | corrections | held-out all frames: learned -> corrected -> after (mm) | "
          "true effect's candidate on its frames before -> after (mm), decision | wall s | cpu s")
    for case in a.cases:
        spec = SynthSpec(object=a.object, interaction=a.interaction, seed=a.seed, preset=a.preset, occlusion="heavy",
                         n_frames=a.frames, effects=HiddenEffects(**CASES[case]))
        sdir = work / "sessions" / f"{a.object}_{a.interaction}_{case}_{a.seed}_{a.preset}_{a.frames or 0}"
        t0, c0 = time.time(), _cpu()
        if not sdir.exists():
            make_session(spec, sdir)
        res = process(sdir, out=None, data_dir=data_dir, preset=a.pipeline_preset, config=None, quiet=True)
        rep = json.loads((Path(res["bundle_dir"]) / "report.json").read_text())
        r = rep.get("residuals") or {}
        if not r:
            print(f"{case} | {CASES[case] or '-'} | residual stage failed: {rep.get('reasons', {})}", flush=True)
            continue
        fitted = {c["effect"]: {k: round(v, 4) for k, v in c["params"].items()} for c in r["candidates"] if c["accepted"]}
        corr = {k: round(v, 3) for k, v in (r.get("corrections") or {}).items()}
        eb = r["error_before"].get("scalar_m")
        ec = (r.get("by_mode", {}).get("error_corrected") or {}).get("scalar_m")
        ea = r["error_after"].get("scalar_m")
        own = "-"
        if case in EXPECTED:
            name, key = EXPECTED[case]
            c = next((c for c in r["candidates"] if c["effect"] == name), None)
            if c is not None:
                truth = CASES[case][case if case != "table_tilt" else "table_tilt"]
                truth = truth[0] if isinstance(truth, tuple) else truth
                own = (f"{name} {key}={c['params'].get(key, float('nan')):.4g} (true {truth}): "
                       f"{_mm(c['heldout_error_before'])} -> {_mm(c['heldout_error_after'])}, "
                       f"{'accepted' if c['accepted'] else c['reason'][:70]}")
        print(f"{case} | {CASES[case] or '-'} | {fitted or '-'} | {corr or '-'} | {_mm(eb)} -> {_mm(ec)} -> {_mm(ea)} | "
              f"{own} | {time.time() - t0:.0f} | {_cpu() - c0:.0f}", flush=True)


if __name__ == "__main__":
    main()
