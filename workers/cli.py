"""The ``vysics`` command line.

    vysics synth   --object baking_box --interaction push --preset tiny --out DIR [--archive FILE]
    vysics run     SESSION --out DIR            (folder or archive; the Prefect flow the API uses)
    vysics serve   [--host H] [--port P]        (the HTTP API)
    vysics worker                               (serve the Prefect deployments; needs PREFECT_API_URL)
    vysics fit-dynamics DATA.npz --out DIR      (contact learning on trajectories alone)
    vysics bench   [--sessions DIR] --out DIR   (dataset benchmark over processed sessions)

Imports are lazy so that ``vysics --help`` is fast. Bad input prints ``file: rule`` and exits 2; a failed
stage prints ``stage: reason`` and exits 1; an unavailable stage exits 3.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
from pathlib import Path

EXIT_FAILED, EXIT_INVALID, EXIT_UNAVAILABLE = 1, 2, 3


def _err(msg: str) -> None:
    print(msg, file=sys.stderr)


def _use_data_dir(data_dir: Path | None) -> Path:
    """Point ``VYSICS_DATA_DIR`` at ``data_dir`` (before settings or prefect are imported)."""
    if data_dir is not None:
        os.environ["VYSICS_DATA_DIR"] = str(Path(data_dir).resolve())
    d = Path(os.environ.get("VYSICS_DATA_DIR", "vysics-data")).resolve()
    os.environ["VYSICS_DATA_DIR"] = str(d)
    return d


# --------------------------------------------------------------------------- synth


def _parse_effect(text: str) -> tuple[str, object]:
    if "=" not in text:
        raise ValueError(f"--effect {text!r}: expected NAME=VALUE (e.g. restitution=0.4, com_offset=0.01,0,0)")
    name, value = text.split("=", 1)
    parts = [float(v) for v in value.split(",")]
    return name.strip(), (parts[0] if len(parts) == 1 else tuple(parts))


def cmd_synth(a: argparse.Namespace) -> int:
    from service.synth import HiddenEffects, SynthSpec, make_archive, make_session

    try:
        hidden = HiddenEffects(**dict(_parse_effect(e) for e in a.effect or []))
    except (TypeError, ValueError) as e:
        _err(f"--effect: {e}")
        return EXIT_INVALID
    occlusion: str | float = a.occlusion
    try:
        occlusion = float(a.occlusion)
    except ValueError:
        pass
    spec = SynthSpec(object=a.object, interaction=a.interaction, seed=a.seed, preset=a.preset, occlusion=occlusion,
                     effects=hidden, noise=not a.no_noise, n_frames=a.frames, declare_mass=not a.undeclared_mass,
                     name=a.name)
    out = Path(a.out) if a.out else Path(spec.session_name())
    bar = _Bar("synth")
    try:
        res = make_session(spec, out, progress=bar)
    except ValueError as e:
        bar.close()
        _err(f"synth: {e}")
        return EXIT_INVALID
    bar.close()
    print(f"session: {res.session_dir} ({res.n_frames} frames, {res.width}x{res.height}, "
          f"occlusion {res.occlusion_mean:.2f}); hidden truth: {res.sidecar_path}")
    if a.archive:
        path = make_archive(res.session_dir, Path(a.archive))
        print(f"archive: {path}")
    return 0


# --------------------------------------------------------------------------- progress


class _Bar:
    """A tqdm bar driven by ``(fraction, message)`` callbacks."""

    def __init__(self, desc: str):
        from tqdm import tqdm

        self.bar = tqdm(total=100, desc=desc, unit="%", file=sys.stderr, dynamic_ncols=True,
                        bar_format="{desc}: {percentage:3.0f}%|{bar}| {postfix}")

    def __call__(self, fraction: float, message: str = "") -> None:
        n = int(round(100 * min(max(float(fraction), 0.0), 1.0)))
        self.bar.update(n - self.bar.n)
        self.bar.set_postfix_str(message[:60], refresh=True)

    def set_desc(self, desc: str) -> None:
        self.bar.set_description_str(desc, refresh=True)

    def close(self) -> None:
        self.bar.close()


class _JobWatcher(threading.Thread):
    """Follows a job's state file and draws one bar per stage (the flow may run in this process or not)."""

    def __init__(self, jobs, job_id: str):
        super().__init__(daemon=True)
        self.jobs, self.job_id = jobs, job_id
        self.stop = threading.Event()
        self.bars: dict[str, _Bar] = {}
        self.last: dict[str, tuple[float, str]] = {}

    def run(self) -> None:
        while not self.stop.is_set():
            self.draw()
            self.stop.wait(0.3)
        self.draw()

    def draw(self) -> None:
        job = self.jobs.get(self.job_id)
        if job is None:
            return
        for stage, st in job["stages"].items():
            if st["state"] == "pending":
                continue
            msg = st.get("message") or st["state"]
            if st["state"] == "skipped":
                msg = f"skipped: {msg}"
            elif st.get("cached"):
                msg = "cached"
            frac = 1.0 if st["state"] == "completed" else float(st["fraction"])
            if self.last.get(stage) == (frac, msg):
                continue
            self.last[stage] = (frac, msg)
            if stage not in self.bars:
                self.bars[stage] = _Bar(f"{stage:>10}")
            self.bars[stage](frac, msg)

    def close(self) -> None:
        self.stop.set()
        self.join(timeout=5)
        for b in self.bars.values():
            b.close()


# --------------------------------------------------------------------------- run


def process(session: Path, *, out: Path | None, data_dir: Path, preset: str | None, config: dict | None,
            quiet: bool = False, stages: str | None = None) -> dict:
    """Run the flow on a session folder or archive; returns the flow's result (raises on failure)."""
    from flows.runtime import configure_prefect

    configure_prefect(data_dir)
    from flows.jobs import JobStore, new_job
    from flows.pipeline import process_session
    from service.session import sha256_of
    from service.settings import Settings

    settings = Settings(data_dir=data_dir)
    jobs = JobStore(settings.jobs_dir)
    sha = sha256_of(session)
    job = new_job(sha, session_sha256=sha, name=None, frames=None, preset=preset or settings.preset, config=config)
    jobs.put(job)
    watcher = None if quiet else _JobWatcher(jobs, sha)
    if watcher:
        watcher.start()
    try:
        return process_session(session=str(session.resolve()), data_dir=str(data_dir), preset=preset, config=config,
                               job_id=sha, out_dir=str(out.resolve()) if out else None, stages=stages)
    finally:
        if watcher:
            watcher.close()


def _quiet_prefect() -> None:
    """Prefect's own INFO lines (server start, task states) would tear through the progress bars."""
    os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")


def cmd_run(a: argparse.Namespace) -> int:
    data_dir = _use_data_dir(a.data_dir)
    _quiet_prefect()
    from service.errors import InvalidSession, StageFailed

    session = Path(a.session)
    if not session.exists():
        _err(f"{session}: no such file or folder")
        return EXIT_INVALID
    config = None
    if a.config:
        try:
            config = json.loads(Path(a.config).read_text())
        except OSError as e:
            _err(f"{a.config}: cannot read ({e.strerror})")
            return EXIT_INVALID
        except ValueError as e:
            _err(f"{a.config}: invalid JSON ({e})")
            return EXIT_INVALID
        if not isinstance(config, dict):
            _err(f"{a.config}: expected a JSON object of per-stage overrides")
            return EXIT_INVALID
    try:  # refuse a bad configuration before anything starts
        from flows.stages import select_stages
        from service.config import PipelineConfig

        PipelineConfig.from_dict({**(config or {}), **({"preset": a.preset} if a.preset else {})})
    except ValueError as e:
        _err(f"{a.config or '--preset'}: {e}")
        return EXIT_INVALID
    try:
        select_stages(a.stages)
    except ValueError as e:
        _err(f"--stages: {e}")
        return EXIT_INVALID
    try:
        res = process(session, out=Path(a.out), data_dir=data_dir, preset=a.preset, config=config, quiet=a.quiet,
                      stages=a.stages)
    except InvalidSession as e:
        _err(f"{e.file}: {e.rule}")
        return EXIT_INVALID
    except StageFailed as e:
        _err(f"{e.stage}: {e.reason}")
        return EXIT_FAILED
    except ValueError as e:  # bad preset / config / stage selection
        _err(f"{a.config or '--preset/--stages'}: {e}")
        return EXIT_INVALID
    print(f"bundle: {Path(a.out).resolve()}  (zip: {res['bundle_zip']})")
    for stage, reason in (res.get("skipped") or {}).items():
        print(f"  {stage}: {reason}")
    return 0


# --------------------------------------------------------------------------- serve / worker


def cmd_serve(a: argparse.Namespace) -> int:
    _use_data_dir(a.data_dir)
    import uvicorn

    from api.settings import ApiSettings

    s = ApiSettings()
    uvicorn.run("api.app:create_app", factory=True, host=a.host or s.api_host, port=a.port or s.api_port,
                log_level=s.log_level.lower())
    return 0


def cmd_worker(a: argparse.Namespace) -> int:
    data_dir = _use_data_dir(a.data_dir)
    from flows.runtime import configure_prefect

    configure_prefect(data_dir)
    if not os.environ.get("PREFECT_API_URL"):
        print("note: PREFECT_API_URL is not set; serving against an embedded Prefect API that only this "
              "process can reach (set it to a Prefect server to take runs from the API)", file=sys.stderr)
    from flows.deployments import serve_deployments

    serve_deployments(reprocess_cron=a.reprocess_cron)
    return 0


def cmd_runner(a: argparse.Namespace) -> int:
    data_dir = _use_data_dir(a.data_dir)
    from workers.runner import run_queue

    run_queue(data_dir, once=a.once)
    return 0


# --------------------------------------------------------------------------- fit-dynamics / bench


def cmd_fit_dynamics(a: argparse.Namespace) -> int:
    """Contact learning then the residual loop (Prefect flow ``fit-dynamics``) on trajectories alone."""
    from service.contact.data import load_trajectories
    from service.errors import InvalidInput

    data = Path(a.data)
    if not data.is_file():
        _err(f"{data}: no such file")
        return EXIT_INVALID
    try:
        load_trajectories(data)  # validate before anything runs or is written
    except InvalidInput as e:
        _err(f"{e.file}: {e.rule}")
        return EXIT_INVALID
    train_ids = [int(x) for x in a.train_ids.split(",")] if a.train_ids else None
    out = Path(a.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    _use_data_dir(getattr(a, "data_dir", None))
    _quiet_prefect()
    from flows import fit_dynamics as fd

    bars: dict[str, _Bar] = {}
    fd.PROGRESS_HOOKS[str(out)] = lambda stage: bars.setdefault(stage, _Bar(stage))
    try:
        result = fd.fit_dynamics(str(data.resolve()), str(out), preset=a.preset or "default", mass=a.mass,
                                 train_ids=train_ids, residuals=not a.no_residuals)
    except InvalidInput as e:
        _err(f"{e.file}: {e.rule}")
        return EXIT_INVALID
    finally:
        fd.PROGRESS_HOOKS.pop(str(out), None)
        for b in bars.values():
            b.close()
    r = result.get("residuals")
    if r is not None:
        print(f"residual loop: accepted {r['accepted'] or 'nothing'}; held-out error {r['error_before']} -> {r['error_after']}")
    print(f"results: {out}")
    return 0


def cmd_bench(a: argparse.Namespace) -> int:
    data_dir = _use_data_dir(a.data_dir)
    _quiet_prefect()
    import importlib

    try:
        bench = importlib.import_module("service.evaluation.bench")
    except ImportError:
        bench = None
    run_bench = getattr(bench, "run_bench", None)
    if run_bench is None:
        _err("bench: stage unavailable: service.evaluation.bench.run_bench does not exist yet")
        return EXIT_UNAVAILABLE
    out = Path(a.out)

    def process_one(session_dir: Path) -> dict:
        res = process(Path(session_dir), out=None, data_dir=data_dir, preset=a.pipeline_preset, config=None,
                      quiet=True)
        return json.loads((Path(res["bundle_dir"]) / "report.json").read_text())

    if a.sessions:
        sessions = Path(a.sessions)
    else:  # every object kind × the given seeds, heavy occlusion (seeds other than the ones tests tune on)
        from service.synth import OBJECT_KINDS

        try:
            seeds = [int(x) for x in str(a.seeds).split(",") if x.strip()]
        except ValueError:
            _err(f"--seeds {a.seeds!r}: expected comma-separated integers")
            return EXIT_INVALID
        if not seeds:
            _err("--seeds: expected at least one seed")
            return EXIT_INVALID
        sessions = bench.default_specs(a.preset, seeds)
        if a.objects:
            want = {x.strip() for x in a.objects.split(",") if x.strip()}
            unknown = sorted(want - set(OBJECT_KINDS))
            if unknown or not want:
                _err(f"--objects: unknown {unknown}, expected names from {list(OBJECT_KINDS)}")
                return EXIT_INVALID
            sessions = [s for s in sessions if s.object in want]
    bar = _Bar("bench")
    res = run_bench(sessions, out, preset=a.preset, process=process_one, progress=bar)
    bar.close()
    print(f"results: {out.resolve()} ({len(res.rows)} rows, {len(res.failures)} failed sessions)")
    for f in res.failures:
        print(f"  {f['session']}: {f['error']}")
    return 0


# --------------------------------------------------------------------------- parser


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vysics", description="Simulation-ready object models from RGBD robot sessions.")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    s = sub.add_parser("synth", help="make a synthetic session (folder, optionally an archive)")
    s.add_argument("--object", default="baking_box",
                   help="object kind: baking_box, bottle, egg, milk_carton, oat_carton, styrofoam, prism, l_block, mug "
                        "(docs/synthetic-lab.md)")
    s.add_argument("--interaction", default="push", choices=["push", "pivot", "topple", "strike"],
                   help="push | pivot | topple | strike (impulsive pushes, the object slides free)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--preset", default="tiny", choices=["tiny", "small", "full"])
    s.add_argument("--frames", type=int, default=None, help="number of frames (default: the preset's)")
    s.add_argument("--occlusion", default="none", help="none | light | heavy, or a hidden fraction in [0, 0.8]")
    s.add_argument("--effect", action="append", metavar="NAME=VALUE",
                   help="hidden effect, repeatable (restitution=0.4, linear_damping=1.5, com_offset=0.01,0,0, ...)")
    s.add_argument("--no-noise", action="store_true", help="no sensor noise")
    s.add_argument("--undeclared-mass", action="store_true", help="leave object.mass null in session.json")
    s.add_argument("--name", default=None, help="session name")
    s.add_argument("--out", default=None, help="session folder to write (default: ./<name>)")
    s.add_argument("--archive", default=None, metavar="FILE", help="also pack it (.zip, .tar, .tar.gz, .tgz)")
    s.set_defaults(func=cmd_synth)

    r = sub.add_parser("run", help="process a session folder or archive and write the bundle")
    r.add_argument("session", help="session folder or .zip/.tar/.tar.gz/.tgz")
    r.add_argument("--out", required=True, help="bundle folder to write")
    r.add_argument("--preset", default=None, choices=["default", "fast"], help="pipeline preset (VYSICS_PRESET)")
    r.add_argument("--config", default=None, help="JSON file of per-stage overrides")
    r.add_argument("--data-dir", default=None, type=Path, help="store (VYSICS_DATA_DIR, default ./vysics-data)")
    r.add_argument("--stages", default=None,
                   help="science stages to run: all | none | tracking,contact,... (default VYSICS_STAGES or all)")
    r.add_argument("--quiet", action="store_true", help="no progress bars")
    r.set_defaults(func=cmd_run)

    v = sub.add_parser("serve", help="run the HTTP API")
    v.add_argument("--host", default=None)
    v.add_argument("--port", type=int, default=None)
    v.add_argument("--data-dir", default=None, type=Path)
    v.set_defaults(func=cmd_serve)

    w = sub.add_parser("worker", help="serve the Prefect deployments process-session and reprocess-datasets")
    w.add_argument("--data-dir", default=None, type=Path)
    w.add_argument("--reprocess-cron", default="0 3 * * *", help="schedule of reprocess-datasets ('' = none)")
    w.set_defaults(func=cmd_worker)

    q = sub.add_parser("runner", help="process queued jobs of the data dir (what the API starts)")
    q.add_argument("--data-dir", default=None, type=Path)
    q.add_argument("--once", action="store_true", help="exit when the queue is empty")
    q.set_defaults(func=cmd_runner)

    f = sub.add_parser("fit-dynamics", help="learn geometry and inertia from object trajectories (.npz)")
    f.add_argument("data", help="trajectories .npz")
    f.add_argument("--out", required=True)
    f.add_argument("--preset", default="default", choices=["default", "fast"])
    f.add_argument("--mass", type=float, default=None, help="kg, if known")
    f.add_argument("--train-ids", default=None, help="comma-separated trajectory ids to train on")
    f.add_argument("--no-residuals", action="store_true", help="skip the residual loop (missing-effect search)")
    f.add_argument("--data-dir", default=None, help="VYSICS_DATA_DIR (Prefect's embedded database lives there)")
    f.set_defaults(func=cmd_fit_dynamics)

    b = sub.add_parser("bench", help="dataset benchmark: tables and figures over processed sessions")
    b.add_argument("--sessions", default=None, help="folder of session folders (default: synthetic set)")
    b.add_argument("--out", required=True)
    b.add_argument("--preset", default="small", help="synthetic preset of generated sessions")
    b.add_argument("--pipeline-preset", default=None, choices=["default", "fast"])
    b.add_argument("--seeds", default="0,1,2", help="seeds of the generated synthetic set (comma separated)")
    b.add_argument("--objects", default=None, help="object kinds to include (comma separated; default: all)")
    b.add_argument("--data-dir", default=None, type=Path)
    b.set_defaults(func=cmd_bench)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        _err("interrupted")
        return 130


if __name__ == "__main__":
    sys.exit(main())
