"""Deployments served by ``vysics worker``: ``process-session`` (runs of the API's uploads when the API
launches through a Prefect server) and ``reprocess-datasets`` (scheduled: re-run stored sessions whose
code/config signature changed; the artifact store makes unchanged stages free)."""

from __future__ import annotations

from pathlib import Path

from flows.runtime import configure_prefect

configure_prefect()

from prefect import flow, get_run_logger, serve  # noqa: E402

from flows import jobs as J  # noqa: E402
from flows.pipeline import pipeline_signature, process_session  # noqa: E402
from flows.sessions import find_root, is_sha  # noqa: E402
from service.config import PipelineConfig  # noqa: E402
from service.settings import Settings, get_settings  # noqa: E402
from service.store import ArtifactStore  # noqa: E402


def stale_sessions(settings: Settings, cfg: PipelineConfig) -> list[str]:
    """Stored sessions without a completed job of the current signature."""
    store = ArtifactStore(settings.artifacts_dir)
    sig = pipeline_signature(cfg, store)
    jobs = J.JobStore(settings.jobs_dir)
    out = []
    if not settings.sessions_dir.is_dir():
        return out
    for d in sorted(settings.sessions_dir.iterdir()):
        if not (d.is_dir() and is_sha(d.name) and find_root(d) is not None):
            continue
        job = jobs.get(d.name)
        if job is not None and job.get("state") in (J.QUEUED, J.RUNNING):
            continue
        if job is None or job.get("state") != J.COMPLETED or job.get("signature") != sig:
            out.append(d.name)
    return out


@flow(name="reprocess-datasets", log_prints=True, retries=0)
def reprocess_datasets(data_dir: str | None = None, preset: str | None = None, limit: int | None = None) -> dict:
    """Re-run every stored session whose last result is out of date (code or config changed)."""
    settings = Settings(data_dir=Path(data_dir)) if data_dir else get_settings()
    cfg = PipelineConfig.preset_named(preset or settings.preset)
    todo = stale_sessions(settings, cfg)[: limit or None]
    log = get_run_logger()
    log.info("%d stored sessions out of date", len(todo))
    done, failed = [], {}
    for sha in todo:
        try:
            process_session(session=sha, data_dir=str(settings.data_dir), preset=cfg.preset, job_id=sha)
            done.append(sha)
        except Exception as e:  # noqa: BLE001 - one session must not stop the others; its job holds the reason
            failed[sha] = f"{type(e).__name__}: {e}"
    return {"reprocessed": done, "failed": failed}


def serve_deployments(reprocess_cron: str | None = "0 3 * * *") -> None:
    """Serve both deployments from this process (blocks)."""
    deployments = [process_session.to_deployment(name="process-session")]
    kw = {"cron": reprocess_cron} if reprocess_cron else {}
    deployments.append(reprocess_datasets.to_deployment(name="reprocess-datasets", **kw))
    serve(*deployments)
