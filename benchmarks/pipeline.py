"""Whole-pipeline benchmark: one 10 s, 640x480 session (synthetic lab, heavy occlusion) through
``flows.process_session``; prints per-stage timings and peak memory against the targets
(≤ 180 s wall, ≤ 4 GB peak resident memory). Never fails on time: it prints figures.

    python benchmarks/pipeline.py                      # generate + whole flow
    python benchmarks/pipeline.py --session DIR        # an existing session folder
    python benchmarks/pipeline.py --preset fast        # the reduced pipeline preset
    python benchmarks/pipeline.py --stage evaluation   # the evaluation stage alone, with the
                                                                      # true model for every method

The session is generated once into ``--work`` (default ``/tmp/vysics-bench-pipeline``) and reused.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import resource
import shlex
import sys
import threading
import time
from pathlib import Path

TARGET_S = 180.0
TARGET_GB = 4.0


class PeakRSS:
    """Samples the resident memory of this process and its children (/proc) every 50 ms."""

    def __init__(self):
        self.peak = 0
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)

    @staticmethod
    def _rss_tree(pid: int) -> int:
        total = 0
        try:
            with open(f"/proc/{pid}/status") as fh:
                for line in fh:
                    if line.startswith("VmRSS:"):
                        total += int(line.split()[1]) * 1024
            with open(f"/proc/{pid}/task/{pid}/children") as fh:
                for c in fh.read().split():
                    total += PeakRSS._rss_tree(int(c))
        except (OSError, ValueError):
            pass
        return total

    def _run(self):
        while not self._stop.is_set():
            self.peak = max(self.peak, self._rss_tree(os.getpid()))
            self._stop.wait(0.05)

    def __enter__(self):
        self._t.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._t.join()
        ru = max(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)
        self.peak = max(self.peak, ru * 1024)


def make_full_session(work: Path, seed: int) -> Path:
    from service.synth import SynthSpec, make_session

    spec = SynthSpec(object="oat_carton", interaction="push", seed=seed, preset="full", occlusion="heavy")
    d = work / spec.session_name()
    if not (d / "session.json").is_file():
        t0 = time.perf_counter()
        make_session(spec, d)
        print(f"generated {d} in {time.perf_counter() - t0:.1f} s")
    return d


def call_flow(session: Path, out: Path, data_dir: Path, preset: str | None) -> dict:
    """Run ``flows.process_session`` on the session folder and return the bundle's report.json."""
    try:
        from flows import process_session  # noqa: PLC0415 (the flow is an optional part for this script)
    except ImportError:
        from flows.pipeline import process_session  # noqa: PLC0415

    fn = getattr(process_session, "fn", process_session)  # a Prefect flow object wraps the function
    params = set(inspect.signature(fn).parameters)
    kwargs = {k: v for k, v in (("data_dir", str(data_dir.resolve())), ("preset", preset), ("out_dir", str(out))) if k in params}
    res = process_session(str(session), **kwargs)
    cands = [out]
    if isinstance(res, dict) and res.get("bundle_dir"):
        cands += [Path(res["bundle_dir"]), Path(res["bundle_dir"]) / "bundle"]
    for cand in cands:
        if (cand / "report.json").is_file():
            print(f"report: {cand / 'report.json'}")
            return json.loads((cand / "report.json").read_text())
    print(f"no report.json found; the flow returned {res!r}")
    return res if isinstance(res, dict) else {"result": repr(res)}


def stage_evaluation(session: Path, work: Path) -> dict:
    """Evaluation stage alone on the session, with the true model (from the synthetic sidecar) for every method."""
    import numpy as np

    from service.evaluation import EvaluationConfig, EvaluationInputs, load_ground_truth, run
    from service.mesh import Mesh
    from service.model import ObjectModel
    from service.session import ingest
    from service.synth.objects import make_object

    t0 = time.perf_counter()
    s = ingest(session, work / "ingested" / session.name)
    t_ingest = time.perf_counter() - t0
    side = json.loads((session.parent / f"{session.name}.effects.json").read_text())
    obj = make_object(side["object"]["kind"])
    true = side["true"]
    parts = tuple(Mesh.from_trimesh(p) for p in obj.parts)
    model = ObjectModel(Mesh.from_trimesh(obj.mesh), parts, true["mass"], True, np.asarray(true["com_mesh"]),
                        np.asarray(true["inertia_mesh"]), s.friction, {})
    gt = load_ground_truth(s.root)
    meths = ("vision_only", "physics_only", "fused")
    inp = EvaluationInputs(s, s.frame_times, gt.X_WG, np.ones(len(gt.X_WG), bool), {m: model.visual for m in meths},
                           {m: model for m in meths})
    t0 = time.perf_counter()
    out = run(inp, EvaluationConfig())
    t_eval = time.perf_counter() - t0
    return {"timings_s": {"ingest": t_ingest, "evaluation": t_eval, "total": t_ingest + t_eval},
            "dynamics": out.dynamics, "geometry": out.geometry}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--session", type=Path, help="session folder (default: generate a full synthetic one)")
    ap.add_argument("--work", type=Path, default=Path("/tmp/vysics-bench-pipeline"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--stage", choices=["all", "evaluation"], default="all")
    ap.add_argument("--preset", default=None, help="pipeline preset: default | fast (default: VYSICS_PRESET)")
    a = ap.parse_args(argv)
    cmd = "python benchmarks/pipeline.py " + " ".join(shlex.quote(x) for x in (argv or sys.argv[1:]))
    a.work.mkdir(parents=True, exist_ok=True)
    # the flow's data (artifacts, jobs, Prefect's embedded database) go under the work folder
    os.environ.setdefault("VYSICS_DATA_DIR", str((a.work / "data").resolve()))
    session = a.session or make_full_session(a.work, a.seed)
    out = a.work / "bundle"
    print(f"session: {session}")
    t0 = time.perf_counter()
    cpu0 = time.process_time()
    with PeakRSS() as mem:
        if a.stage == "evaluation":
            rep = stage_evaluation(session, a.work)
        else:
            try:
                rep = call_flow(session, out, a.work / "data", a.preset)
            except ImportError as e:
                print(f"flows.process_session is not available ({e}); nothing measured")
                return 2
    wall = time.perf_counter() - t0
    cpu = time.process_time() - cpu0 + resource.getrusage(resource.RUSAGE_CHILDREN).ru_utime
    load = os.getloadavg()[0]
    print("\nstage timings (s):")
    skipped = {k: v.get("reason") for k, v in (rep.get("stages") or {}).items() if isinstance(v, dict) and not v.get("ran", True)}
    for k, v in (rep.get("timings_s") or {}).items():
        note = f"   (skipped: {skipped[k]})" if k in skipped else ""
        print(f"  {k:<12} {v:8.1f}" if isinstance(v, (int, float)) else f"  {k:<12} {'—':>8}{note}")
    gb = mem.peak / 1024**3
    print(f"\ncpu time    {cpu:8.1f} s   (load average {load:.1f} on {os.cpu_count()} cores: wall time is inflated "
          f"when the load exceeds the core count)")
    print(f"wall time   {wall:8.1f} s   (target ≤ {TARGET_S:.0f} s: {'met' if wall <= TARGET_S else 'NOT met'})")
    print(f"peak memory {gb:8.2f} GB  (target ≤ {TARGET_GB:.0f} GB: {'met' if gb <= TARGET_GB else 'NOT met'})")
    for sec in ("geometry", "dynamics"):
        for m, d in (rep.get(sec) or {}).items():
            vals = {k: round(v, 4) for k, v in (d or {}).items() if isinstance(v, float)}
            print(f"  {sec}/{m}: {vals}")
    print(f"\nreproduce: {cmd}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
