"""API contract over real HTTP: uvicorn listening on a loopback port, the local runner, the Prefect flow."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import threading
import time
import zipfile
from pathlib import Path

import httpx
import pytest
import uvicorn

from api.app import create_app
from api.settings import ApiSettings
from flows.jobs import STAGE_ORDER
from service.bundle import REQUIRED_FILES
from service.report.json import missing_keys
from tests.flows.harness import free_port, tiny_session

PROBLEM = "application/problem+json"
POLL_LIMIT_S = 900  # a guard against hanging, not a speed requirement


@pytest.fixture(scope="module")
def archive(tmp_path_factory) -> Path:
    from service.synth import make_archive

    d = tmp_path_factory.mktemp("sessions")
    folder = tiny_session(d / "box_push", frames=6)
    return make_archive(folder, d / "box_push.zip")


@pytest.fixture(scope="module")
def server(tmp_path_factory, prefect_server):
    # the runner runs ingest and bundle only: these tests are about the service, not the science stages
    old_stages = os.environ.get("VYSICS_STAGES")
    os.environ["VYSICS_STAGES"] = "none"
    data = tmp_path_factory.mktemp("apidata")
    settings = ApiSettings(data_dir=data, preset="fast", launcher="local", runner_poll_s=0.2)
    app = create_app(settings)
    port = free_port()
    srv = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", lifespan="on"))
    th = threading.Thread(target=srv.run, daemon=True)
    th.start()
    t0 = time.monotonic()
    while not srv.started:
        assert th.is_alive() and time.monotonic() - t0 < 120, "uvicorn did not start"
        time.sleep(0.05)
    with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=120) as client:
        yield client, data
    srv.should_exit = True
    th.join(timeout=30)
    if old_stages is None:
        os.environ.pop("VYSICS_STAGES", None)
    else:
        os.environ["VYSICS_STAGES"] = old_stages


def _upload(client: httpx.Client, path: Path, name: str | None = None) -> httpx.Response:
    with open(path, "rb") as f:
        return client.post("/v1/sessions", files={"file": (name or path.name, f, "application/zip")})


def _wait(client: httpx.Client, sid: str) -> dict:
    t0 = time.monotonic()
    while True:
        r = client.get(f"/v1/sessions/{sid}")
        assert r.status_code == 200
        st = r.json()
        if st["state"] in ("completed", "failed"):
            return st
        assert time.monotonic() - t0 < POLL_LIMIT_S, f"job still {st['state']}: {st['stages']}"
        time.sleep(0.5)


def test_healthz_and_openapi(server):
    client, _ = server
    assert client.get("/healthz").json()["status"] == "ok"
    spec = client.get("/openapi.json").json()
    assert {"/v1/sessions", "/v1/sessions/{session_id}", "/v1/sessions/{session_id}/bundle",
            "/v1/sessions/{session_id}/report", "/healthz"} <= set(spec["paths"])
    assert {"SessionAccepted", "SessionStatus", "Problem"} <= set(spec["components"]["schemas"])


def test_upload_process_and_download(server, archive):
    client, data = server
    r = _upload(client, archive)
    assert r.status_code == 202, r.text
    body = r.json()
    sid = body["id"]
    assert len(sid) == 64 and body["created"] is True and body["state"] in ("queued", "running", "completed")
    assert body["session"]["frames"] == 6
    assert body["links"]["bundle"].endswith(f"/v1/sessions/{sid}/bundle")
    assert (data / "sessions" / sid).is_dir()

    early = client.get(f"/v1/sessions/{sid}").json()
    assert set(STAGE_ORDER) <= set(early["stages"])
    if early["state"] != "completed":
        nr = client.get(f"/v1/sessions/{sid}/bundle")
        assert nr.status_code == 409 and nr.headers["content-type"].startswith(PROBLEM)

    st = _wait(client, sid)
    assert st["state"] == "completed", st["error"]
    assert st["error"] is None
    assert st["stages"]["ingest"]["state"] == "completed" and st["stages"]["bundle"]["state"] == "completed"
    for s in STAGE_ORDER:
        assert st["stages"][s]["state"] in ("completed", "skipped"), (s, st["stages"][s])

    rb = client.get(f"/v1/sessions/{sid}/bundle")
    assert rb.status_code == 200 and rb.headers["content-type"] == "application/zip"
    z = zipfile.ZipFile(io.BytesIO(rb.content))
    names = set(z.namelist())
    report = json.loads(z.read("report.json"))
    assert {"report.json", "report.html"} <= names
    assert missing_keys(report) == []
    assert report["format"] == "vysics-report/1"
    assert report["session"] == {"name": body["session"]["name"], "sha256": sid, "frames": 6}
    assert report["timings_s"]["ingest"] > 0 and report["timings_s"]["total"] >= report["timings_s"]["ingest"]
    # every file of the bundle format is there, or the report says why not
    for f in REQUIRED_FILES:
        assert f in names or report["bundle"]["missing"].get(f), f
    assert set(report["bundle"]["files"]) <= names
    assert "object.urdf" in names or report["model"].get("reason")

    rr = client.get(f"/v1/sessions/{sid}/report")
    assert rr.status_code == 200 and rr.json() == report

    # the same bytes again: same id, the completed job is not restarted
    again = _upload(client, archive, name="renamed.zip")
    assert again.status_code == 202
    assert again.json()["id"] == sid and again.json()["created"] is False and again.json()["state"] == "completed"
    st2 = client.get(f"/v1/sessions/{sid}").json()
    assert st2["started"] == st["started"] and st2["finished"] == st["finished"]


def test_bad_archive_is_refused_and_nothing_is_stored(server, tmp_path):
    client, data = server
    before = sorted(p.name for p in (data / "sessions").iterdir())
    jobs_before = sorted(p.name for p in (data / "jobs").iterdir())
    bad = tmp_path / "broken.zip"
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("session.json", json.dumps({"format": "vysics-session/1", "name": "x", "fps": 30.0}))
    bad.write_bytes(buf.getvalue())
    r = _upload(client, bad)
    assert r.status_code == 422
    assert r.headers["content-type"].startswith(PROBLEM)
    p = r.json()
    assert p["status"] == 422 and p["file"] and p["rule"]
    assert p["detail"] == f"{p['file']}: {p['rule']}"

    junk = tmp_path / "junk.zip"
    junk.write_bytes(b"this is not an archive")
    r2 = _upload(client, junk)
    assert r2.status_code == 422 and r2.json()["file"] == "junk.zip"

    assert sorted(p.name for p in (data / "sessions").iterdir()) == before
    assert sorted(p.name for p in (data / "jobs").iterdir()) == jobs_before
    assert list((data / "uploads").iterdir()) == []


def test_unknown_id_and_missing_file_field(server):
    client, _ = server
    for path in ("/v1/sessions/" + "0" * 64, "/v1/sessions/" + "0" * 64 + "/bundle", "/v1/sessions/nope/report"):
        r = client.get(path)
        assert r.status_code == 404 and r.headers["content-type"].startswith(PROBLEM), path
    r = client.post("/v1/sessions", data={"other": "x"})
    assert r.status_code == 422 and r.json()["file"] == "file"


def test_upload_over_the_cap_is_413(tmp_path, monkeypatch, archive):
    from fastapi.testclient import TestClient

    monkeypatch.setenv("VYSICS_LIMIT_MAX_UPLOAD_BYTES", "1000")
    app = create_app(ApiSettings(data_dir=tmp_path, launcher="none"))
    with TestClient(app) as client:
        r = _upload(client, archive)
    assert r.status_code == 413 and r.headers["content-type"].startswith(PROBLEM)
    assert "1000" in r.json()["detail"]
    assert not any((tmp_path / "sessions").iterdir())


def test_importing_the_api_does_not_import_torch():
    code = ("import sys; import api.app; api.app.create_app(); "
            "bad = [m for m in ('torch', 'service.tracking.run', 'service.contact.fit') if m in sys.modules]; "
            "print(bad); sys.exit(1 if bad else 0)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr


def test_failed_job_status_and_results(server):
    from flows.jobs import JobStore, new_job

    client, data = server
    jid = "f" * 64
    jobs = JobStore(data / "jobs")
    job = new_job(jid, session_sha256=jid, name="broken", frames=3, preset="fast")
    job["state"] = "running"  # never queued: the runner must not pick it up
    jobs.put(job)
    jobs.fail(jid, "contact", "no contact between the robot and the object in any frame")
    st = client.get(f"/v1/sessions/{jid}").json()
    assert st["state"] == "failed"
    assert st["error"] == {"stage": "contact", "reason": "no contact between the robot and the object in any frame"}
    assert st["stages"]["contact"]["state"] == "failed"
    for what in ("bundle", "report"):
        r = client.get(f"/v1/sessions/{jid}/{what}")
        assert r.status_code == 409 and r.headers["content-type"].startswith(PROBLEM)
        assert r.json()["stage"] == "contact" and "no contact" in r.json()["detail"]
