"""The Prefect flow ``process-session``: ingest -> science stages -> bundle, one job.

Thin on purpose: each task loads references, calls one ``service`` entry point through
``flows.stages.run_cached`` (which owns caching: tasks use ``cache_policy=NONE``, ``retries=0``), stores
the result and returns an ``ArtifactRef``. Job state (``flows.jobs``) is updated at every step so the API
and the command line can follow the run from any process.
"""

from __future__ import annotations

import logging
import time
import traceback
from pathlib import Path
from typing import Any

from flows.runtime import configure_prefect

configure_prefect()

from prefect import flow, get_run_logger, task  # noqa: E402
from prefect.cache_policies import NONE  # noqa: E402

from flows import jobs as J  # noqa: E402
from flows.sessions import is_sha, load_stored, store_upload  # noqa: E402
from flows.stages import NOT_AVAILABLE, PIPELINE, STAGES, StageContext, run_cached, select_stages  # noqa: E402
from service.config import PipelineConfig  # noqa: E402
from service.errors import InvalidSession, StageFailed  # noqa: E402
from service.settings import Settings, get_settings  # noqa: E402
from service.store import ArtifactRef, ArtifactStore  # noqa: E402

log = logging.getLogger("vysics.flows")
FLOW_NAME = "process-session"


def _settings(data_dir: str | None) -> Settings:
    return Settings(data_dir=Path(data_dir)) if data_dir else get_settings()


def _logger():
    try:
        return get_run_logger()
    except Exception:  # noqa: BLE001 - outside a run context
        return log


class _PrefectProgress:
    """Forwards stage progress to a Prefect progress artifact (best effort, at most once a second)."""

    def __init__(self, stage: str):
        self.stage, self.id, self.last = stage, None, None

    def __call__(self, fraction: float, message: str) -> None:
        now = time.monotonic()
        if fraction < 1.0 and self.last is not None and now - self.last < 1.0:
            return
        self.last = now
        from prefect.artifacts import create_progress_artifact, update_progress_artifact

        if self.id is None:
            self.id = create_progress_artifact(progress=100.0 * fraction, description=f"{self.stage}: {message}")
        else:
            update_progress_artifact(self.id, progress=100.0 * fraction, description=f"{self.stage}: {message}")


def _bridge(jobs: J.JobStore, job_id: str, stage: str) -> J.ProgressBridge:
    return J.ProgressBridge(jobs, job_id, stage, also=_PrefectProgress(stage))


@task(name="ingest", cache_policy=NONE, retries=0)
def ingest_task(session: str, data_dir: str, job_id: str | None) -> dict:
    """Store (validate + unpack) a session folder/archive, or find a stored one by sha256."""
    settings = _settings(data_dir)
    store = ArtifactStore(settings.artifacts_dir)
    progress = _bridge(J.JobStore(settings.jobs_dir), job_id, "ingest") if job_id else None
    if is_sha(session):
        _, st = load_stored(settings.data_dir, session, store)
    else:
        _, st = store_upload(Path(session), settings.data_dir, limits=settings.limits, progress=progress, store=store)
    _logger().info("session %s (%s, %d frames) %s", st.sha256[:12], st.name, st.frames,
                   "already stored" if st.reused else "stored")
    return {"sha256": st.sha256, "name": st.name, "frames": st.frames, "root": str(st.root),
            "ingest_ref": st.ingest_ref, "seconds": st.ingest_seconds, "reused": st.reused}


@task(name="stage", cache_policy=NONE, retries=0, task_run_name="{stage}")
def stage_task(stage: str, refs: dict[str, ArtifactRef], sha256: str, data_dir: str, job_id: str,
               config: dict) -> dict:
    """Run one science stage through the store (computed once per key)."""
    settings = _settings(data_dir)
    store = ArtifactStore(settings.artifacts_dir)
    jobs = J.JobStore(settings.jobs_dir)
    spec = STAGES[stage]
    session, _ = load_stored(settings.data_dir, sha256, store)
    cfg = PipelineConfig.from_dict(config).stage(stage)
    ctx = StageContext(session=session, store=store, refs=dict(refs))
    jobs.stage(job_id, stage, state=J.RUNNING, fraction=0.0, message="starting")
    res = run_cached(spec, ctx, cfg, progress=_bridge(jobs, job_id, stage))
    jobs.stage(job_id, stage, state=J.COMPLETED, fraction=1.0, cached=res.cached, seconds=res.seconds,
               message="cached" if res.cached else "done")
    _logger().info("session %s stage %s: %s in %.2f s", sha256[:12], stage, "cached" if res.cached else "computed",
                   res.seconds)
    return {"ref": res.ref, "seconds": res.seconds, "cached": res.cached}


@task(name="bundle", cache_policy=NONE, retries=0)
def bundle_task(refs: dict[str, ArtifactRef], timings: dict[str, float], reasons: dict[str, str], sha256: str,
                data_dir: str, job_id: str, config: dict) -> dict:
    """Write the bundle (folder + zip) as a stored artifact keyed by every input artifact."""
    from service.bundle import parts_from_outputs, write_bundle

    settings = _settings(data_dir)
    store = ArtifactStore(settings.artifacts_dir)
    jobs = J.JobStore(settings.jobs_dir)
    cfg = PipelineConfig.from_dict(config)
    session, _ = load_stored(settings.data_dir, sha256, store)
    jobs.stage(job_id, "bundle", state=J.RUNNING, fraction=0.0, message="writing")
    inputs = {k: r.key for k, r in refs.items()}
    key = store.key("bundle", inputs, {"export": cfg.export, "reasons": reasons})
    ref = store.get("bundle", key)
    cached = ref is not None
    if ref is None:
        outputs = {s: store.load(STAGES[s].output_type(), refs[s]) for s in refs if s in STAGES}

        def write(folder: Path) -> None:
            parts = parts_from_outputs(session=session, outputs=outputs, timings_s=timings, reasons=reasons,
                                       export_config=cfg.export, plots_dir=folder / "figures")
            write_bundle(parts, folder / "bundle", zip_path=folder / "bundle.zip")

        ref = store.put("bundle", key, write, inputs=inputs, config={"export": cfg.export, "reasons": reasons})
    seconds = float(store.manifest(ref)["timings_s"].get("bundle", 0.0))
    jobs.stage(job_id, "bundle", state=J.COMPLETED, fraction=1.0, cached=cached, seconds=seconds,
               message="cached" if cached else "done")
    return {"ref": ref, "zip": str(Path(ref.path) / "bundle.zip"), "folder": str(Path(ref.path) / "bundle")}


def pipeline_signature(cfg: PipelineConfig, store: ArtifactStore) -> str:
    """sha256 of every stage's code version and the config: a stored session whose last completed job has
    another signature is out of date (``reprocess-datasets`` runs it again; unchanged stages are cached)."""
    import hashlib
    import json

    stages = ("ingest", *(s.name for s in PIPELINE), "bundle")
    payload = {"code": {s: store.code_version(s) for s in stages}, "config": cfg.to_dict()}
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


def _ensure_job(jobs: J.JobStore, job_id: str, st: dict, cfg: PipelineConfig) -> None:
    job = jobs.get(job_id)
    if job is None:
        job = J.new_job(job_id, session_sha256=st["sha256"], name=st["name"], frames=st["frames"],
                        preset=cfg.preset, config=cfg.to_dict())
        job["state"] = J.RUNNING
        job["started"] = J.now_iso()
        jobs.put(job)
        return

    def fn(j: dict) -> None:
        j["state"] = J.RUNNING
        j["started"] = j.get("started") or J.now_iso()
        j["warnings"] = []
        for name, stage in j["stages"].items():  # a new run: forget the stages of the previous one
            if name != "ingest":
                stage.update(state=J.PENDING, fraction=0.0, message="", cached=False, seconds=None)
        j["session"] = {"sha256": st["sha256"], "name": st["name"], "frames": st["frames"]}
        j["error"] = None

    jobs.update(job_id, fn)


@flow(name=FLOW_NAME, log_prints=True, retries=0)
def process_session(session: str, data_dir: str | None = None, preset: str | None = None,
                    config: dict[str, Any] | None = None, job_id: str | None = None,
                    out_dir: str | None = None, stages: str | list[str] | None = None) -> dict:
    """Process one session end to end and return ``{job_id, sha256, bundle_zip, bundle_dir, stages}``.

    ``session``: a session folder or archive path, or the sha256 of a stored session. ``preset``:
    ``default`` | ``fast`` (default ``VYSICS_PRESET``); ``config``: per-stage overrides (PipelineConfig JSON).
    ``job_id``: the job to report into (default: the session's sha256). ``out_dir``: also copy the bundle
    folder there (command line). ``stages``: which science stages to run (``"all"``, ``"none"``, ``"a,b"`` or a
    list; default ``VYSICS_STAGES`` or all); the others are skipped with that reason.
    A required stage that fails fails the job; a measuring stage (evaluation, residuals) that fails leaves
    its report section empty with the reason, and the job completes.
    """
    settings = _settings(data_dir)
    data_dir = str(settings.data_dir)
    config = dict(config or {})
    config["preset"] = preset or config.get("preset") or settings.preset
    cfg = PipelineConfig.from_dict(config)
    config = cfg.to_dict()
    selected = select_stages(stages)
    jobs = J.JobStore(settings.jobs_dir)
    current = "ingest"
    try:
        if job_id is not None and jobs.exists(job_id):
            jobs.stage(job_id, "ingest", state=J.RUNNING, fraction=0.0, message="reading session")
        st = ingest_task(session, data_dir, job_id if job_id and jobs.exists(job_id) else None)
        job_id = job_id or st["sha256"]
        _ensure_job(jobs, job_id, st, cfg)
        jobs.stage(job_id, "ingest", state=J.COMPLETED, fraction=1.0, seconds=st["seconds"], cached=st["reused"],
                   message="stored before" if st["reused"] else "validated and stored")
        refs: dict[str, ArtifactRef] = {"ingest": st["ingest_ref"]}
        timings: dict[str, float] = {"ingest": st["seconds"]}
        reasons: dict[str, str] = {}
        for spec in PIPELINE:
            current = spec.name
            missing = [r for r in spec.requires if r not in refs]
            if selected is not None and spec.name not in selected:
                reason = "not selected (stages setting)"
            elif missing:
                reason = f"needs {missing[0]} ({reasons.get(missing[0], NOT_AVAILABLE)})"
            else:
                reason = spec.unavailable_reason()
            if reason:
                reasons[spec.name] = reason
                jobs.stage(job_id, spec.name, state=J.SKIPPED, fraction=0.0, message=reason)
                continue
            try:
                res = stage_task(spec.name, refs, st["sha256"], data_dir, job_id, config)
            except StageFailed as e:
                if spec.required:
                    raise
                reasons[spec.name] = f"failed: {e.reason}"
                jobs.stage(job_id, spec.name, state=J.FAILED, message=e.reason)
                warning = {"stage": e.stage, "reason": e.reason}
                jobs.update(job_id, lambda j: j.setdefault("warnings", []).append(warning))
                _logger().warning("session %s: %s failed, continuing without it: %s", st["sha256"][:12], e.stage,
                                  e.reason)
                continue
            refs[spec.name] = res["ref"]
            timings[spec.name] = res["seconds"]
        current = "bundle"
        b = bundle_task(refs, timings, reasons, st["sha256"], data_dir, job_id, config)
        if out_dir:
            from service.bundle import copy_bundle

            copy_bundle(Path(b["folder"]), Path(out_dir))
        jobs.finish(job_id, bundle=b["zip"])
        jobs.update(job_id, lambda j: j.update(signature=pipeline_signature(cfg, ArtifactStore(settings.artifacts_dir))))
        return {"job_id": job_id, "sha256": st["sha256"], "bundle_zip": b["zip"], "bundle_dir": b["folder"],
                "skipped": reasons}
    except StageFailed as e:
        if job_id and jobs.exists(job_id):
            jobs.fail(job_id, e.stage, e.reason)
        raise
    except InvalidSession as e:
        if job_id and jobs.exists(job_id):
            jobs.fail(job_id, "ingest", f"{e.file}: {e.rule}")
        raise
    except Exception as e:
        log.error("session %s: %s failed\n%s", session, current, traceback.format_exc())
        if job_id and jobs.exists(job_id):
            jobs.fail(job_id, current, f"{type(e).__name__}: {e}")
        raise
