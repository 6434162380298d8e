"""The residual loop on synthetic-lab sessions with hidden effects, through the whole pipeline.

Each session is generated with one hidden effect (written only to the sidecar, never told to the service),
processed by the same flow as the API (tracking -> contact -> fusion -> evaluation -> residuals), and the
report's residual block is compared with the sidecar's truth. Prints one row per session.

    python benchmarks/residuals_pipeline.py [--preset small] [--seed 21] [--object milk_carton] [--work DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

CASES = {
    "none": {},
    "friction_object_table": {"friction_object_table": 0.5},
    "clock_offset": {"clock_offset": 0.1},
    "table_tilt": {"table_tilt": (0.05, 0.0)},
    "linear_damping": {"linear_damping": 3.0},
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="small")
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

    print(f"# python benchmarks/residuals_pipeline.py --preset {a.preset} --seed {a.seed} --object {a.object} "
          f"--interaction {a.interaction}")
    print("case | true | accepted | fitted | held-out error before -> after (m) | wall s")
    for case in a.cases:
        spec = SynthSpec(object=a.object, interaction=a.interaction, seed=a.seed, preset=a.preset, occlusion="heavy",
                         effects=HiddenEffects(**CASES[case]))
        sdir = work / "sessions" / f"{a.object}_{case}_{a.seed}"
        if not sdir.exists():
            make_session(spec, sdir)
        t0 = time.time()
        res = process(sdir, out=None, data_dir=data_dir, preset=a.pipeline_preset, config=None, quiet=True)
        rep = json.loads((Path(res["bundle_dir"]) / "report.json").read_text())
        r = rep["residuals"]
        fitted = {c["effect"]: c["params"] for c in r["candidates"] if c["accepted"]}
        eb, ea = r["error_before"].get("pos_err_m"), r["error_after"].get("pos_err_m")
        print(f"{case} | {CASES[case] or '-'} | {r['accepted'] or '-'} | {json.dumps(fitted)} | "
              f"{eb if eb is None else round(eb, 4)} -> {ea if ea is None else round(ea, 4)} | {time.time() - t0:.0f}",
              flush=True)


if __name__ == "__main__":
    main()
