"""What the service plumbing costs around the science: Prefect start-up, ingest + bundle, cached re-runs.

    python benchmarks/service_overhead.py [--frames 60] [--full] [--out benchmarks/results/service_overhead]

Prints, for one synthetic session (tiny preset):
- embedded Prefect API start-up (the first flow run of a process pays it once);
- a flow with no science stage (ingest: validate + unpack + store; bundle: report + zip), cold and cached;
- with ``--full``, the whole pipeline at the ``fast`` preset, cold and then fully cached (a re-run reads every
  stage from the artifact store), with each stage's time from the job state.
Timings are wall-clock on this machine (shared cores: expect noise); nothing here fails on time.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--full", action="store_true", help="also run every science stage (fast preset)")
    ap.add_argument("--out", default=None, help="keep the data dir here (default: a temporary folder)")
    a = ap.parse_args()
    data = Path(a.out) if a.out else Path(tempfile.mkdtemp(prefix="vysics-overhead-"))
    if data.exists():
        shutil.rmtree(data)
    data.mkdir(parents=True)
    os.environ["VYSICS_DATA_DIR"] = str(data)
    os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
    from flows.runtime import configure_prefect

    configure_prefect(data)
    from service.synth import SynthSpec, make_archive, make_session

    t0 = time.perf_counter()
    s = make_session(SynthSpec(preset="tiny", n_frames=a.frames), data / "src" / "session")
    archive = make_archive(s.session_dir, data / "src" / "session.zip")
    print(f"synthetic session: {a.frames} frames 160x120, archive {archive.stat().st_size / 1e6:.2f} MB "
          f"({time.perf_counter() - t0:.1f} s to make)")

    t0 = time.perf_counter()
    from prefect.server.api.server import SubprocessASGIServer

    SubprocessASGIServer().start(timeout=600)
    print(f"embedded Prefect API start-up: {time.perf_counter() - t0:.1f} s")
    from flows.jobs import JobStore
    from flows.pipeline import process_session

    jobs = JobStore(data / "jobs")

    def run(label: str, stages: str, preset: str = "fast") -> dict:
        t = time.perf_counter()
        res = process_session(session=str(archive), data_dir=str(data), preset=preset, stages=stages)
        wall = time.perf_counter() - t
        job = jobs.get(res["job_id"])
        per = {k: v["seconds"] for k, v in job["stages"].items() if v["seconds"] is not None}
        cached = [k for k, v in job["stages"].items() if v.get("cached")]
        print(f"{label}: {wall:.2f} s wall; stage seconds {json.dumps({k: round(v, 2) for k, v in per.items()})}; "
              f"cached {cached}")
        return res

    run("flow, no science stage, cold  ", "none")
    run("flow, no science stage, cached", "none")
    if a.full:
        run("flow, all stages (fast), cold  ", "all")
        run("flow, all stages (fast), cached", "all")
    print(f"data dir: {data}")
    print("reproduce: python benchmarks/service_overhead.py " + " ".join(sys.argv[1:]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
