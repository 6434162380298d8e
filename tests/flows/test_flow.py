"""The Prefect flow end to end on a tiny session: stage wiring, failure into job state, reprocessing."""

from __future__ import annotations

import numpy as np
import pytest

from flows import jobs as J
from flows.stages import STAGES, StageSpec
from service.errors import StageFailed
from tests.flows import fake_stage
from tests.flows.fake_stage import FakeConfig, FakeInputs
from tests.flows.harness import tiny_session


@pytest.fixture(scope="module")
def session_dir(tmp_path_factory):
    return tiny_session(tmp_path_factory.mktemp("flow") / "s", frames=4, seed=5)


def _with_fake_stage(monkeypatch, fail: bool, required: bool = True):
    import flows.pipeline as P
    from service.config import PipelineConfig

    spec = StageSpec("fake", "tests.flows.fake_stage", "tests.flows.fake_stage:FakeOutputs", (),
                     lambda ctx: FakeInputs(np.full(3, float(ctx.session.n_frames))), required=required)
    monkeypatch.setattr(P, "PIPELINE", (spec,))
    monkeypatch.setitem(STAGES, "fake", spec)
    monkeypatch.setattr(PipelineConfig, "stage", lambda self, name: FakeConfig(fail=fail) if name == "fake" else None)
    return P


def test_wired_stage_runs_is_cached_and_timed(monkeypatch, session_dir, tmp_path, prefect_server):
    P = _with_fake_stage(monkeypatch, fail=False)
    fake_stage.CALLS["n"] = 0
    res = P.process_session(session=str(session_dir), data_dir=str(tmp_path), preset="fast")
    jobs = J.JobStore(tmp_path / "jobs")
    job = jobs.get(res["job_id"])
    assert job["state"] == J.COMPLETED and job["stages"]["fake"]["state"] == J.COMPLETED
    assert job["stages"]["fake"]["cached"] is False and fake_stage.CALLS["n"] == 1
    import json
    from pathlib import Path

    report = json.loads((Path(res["bundle_dir"]) / "report.json").read_text())
    assert report["timings_s"]["fake"] == pytest.approx(job["stages"]["fake"]["seconds"])

    P.process_session(session=res["sha256"], data_dir=str(tmp_path), preset="fast", job_id=res["job_id"])
    assert fake_stage.CALLS["n"] == 1  # the store answered
    assert jobs.get(res["job_id"])["stages"]["fake"]["cached"] is True


def test_stage_failure_becomes_job_state(monkeypatch, session_dir, tmp_path, prefect_server):
    P = _with_fake_stage(monkeypatch, fail=True)
    with pytest.raises(StageFailed) as ei:
        P.process_session(session=str(session_dir), data_dir=str(tmp_path), preset="fast")
    assert ei.value.stage == "fake"
    (job,) = J.JobStore(tmp_path / "jobs").list()
    assert job["state"] == J.FAILED
    assert job["error"]["stage"] == "fake" and "told to fail" in job["error"]["reason"]
    assert "Traceback" not in job["error"]["reason"]
    assert job["stages"]["fake"]["state"] == J.FAILED and job["stages"]["ingest"]["state"] == J.COMPLETED


def test_failed_measuring_stage_does_not_fail_the_job(monkeypatch, session_dir, tmp_path, prefect_server):
    import json
    from pathlib import Path

    P = _with_fake_stage(monkeypatch, fail=True, required=False)
    res = P.process_session(session=str(session_dir), data_dir=str(tmp_path), preset="fast")
    job = J.JobStore(tmp_path / "jobs").get(res["job_id"])
    assert job["state"] == J.COMPLETED and job["error"] is None
    assert job["stages"]["fake"]["state"] == J.FAILED
    assert job["warnings"][0]["stage"] == "fake" and "told to fail" in job["warnings"][0]["reason"]
    report = json.loads((Path(res["bundle_dir"]) / "report.json").read_text())
    assert report["stages"]["fake"]["ran"] is False and "told to fail" in report["stages"]["fake"]["reason"]
    assert "told to fail" in res["skipped"]["fake"]


def test_stage_selection(session_dir, tmp_path, prefect_server):
    from flows.pipeline import process_session
    from flows.stages import select_stages

    assert select_stages("none") == () and select_stages("all") is None and select_stages("tracking") == ("tracking",)
    with pytest.raises(ValueError):
        select_stages("tracking,warp_drive")
    res = process_session(session=str(session_dir), data_dir=str(tmp_path), preset="fast", stages="none")
    job = J.JobStore(tmp_path / "jobs").get(res["job_id"])
    assert job["state"] == J.COMPLETED
    for s in STAGES:
        assert job["stages"][s]["state"] == "skipped" and "not selected" in job["stages"][s]["message"]


def test_reprocess_finds_out_of_date_sessions(session_dir, tmp_path, prefect_server):
    from flows.deployments import stale_sessions
    from flows.pipeline import process_session
    from service.config import PipelineConfig
    from service.settings import Settings

    settings = Settings(data_dir=tmp_path)
    res = process_session(session=str(session_dir), data_dir=str(tmp_path), preset="fast", stages="none")
    assert stale_sessions(settings, PipelineConfig.preset_named("fast")) == []
    assert stale_sessions(settings, PipelineConfig.preset_named("default")) == [res["sha256"]]


def test_deployments_are_defined():
    from flows.deployments import process_session, reprocess_datasets

    d = process_session.to_deployment(name="process-session")
    assert (d.flow_name, d.name) == ("process-session", "process-session")
    r = reprocess_datasets.to_deployment(name="reprocess-datasets", cron="0 3 * * *")
    assert r.schedules and r.schedules[0].schedule.cron == "0 3 * * *"
