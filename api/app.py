"""The HTTP API: ``create_app(settings)``.

``POST /v1/sessions`` (multipart, field ``file``): the upload is streamed to disk under the size cap
(413 beyond it), validated (``service.session.ingest``; 422 naming the file and the rule, and nothing is
kept), stored by sha256 under ``sessions/<sha256>/`` and a job is queued; the answer is 202 with the id
(= sha256: the same bytes give the same id, and a completed job is not restarted). ``GET
/v1/sessions/{id}`` is the job state with per-stage progress and, on failure, the stage and the reason.
``GET /v1/sessions/{id}/bundle`` and ``/report`` serve the result (409 until it exists). Errors are
``application/problem+json``. This package never imports torch.
"""

from __future__ import annotations

import hashlib
import logging
import re
import shutil
import uuid
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Annotated

from fastapi import Depends, FastAPI, File, Request, UploadFile
from fastapi.responses import FileResponse, JSONResponse
from starlette.concurrency import run_in_threadpool

import service
from api import problems
from api.launcher import Launcher, make_launcher
from api.models import Health, Links, Problem, SessionAccepted, SessionInfo, SessionStatus
from api.problems import ApiProblem
from api.settings import ApiSettings
from flows import jobs as J

log = logging.getLogger("vysics.api")
CHUNK = 1 << 20
SAFE_NAME = re.compile(r"[^A-Za-z0-9._-]+")
PROBLEM_RESPONSES = {
    404: {"model": Problem, "description": "unknown session id", "content": {"application/problem+json": {}}},
    409: {"model": Problem, "description": "result not ready (or the job failed)",
          "content": {"application/problem+json": {}}},
    413: {"model": Problem, "description": "upload larger than the size cap", "content": {"application/problem+json": {}}},
    422: {"model": Problem, "description": "invalid session: names the file and the rule",
          "content": {"application/problem+json": {}}},
}


class UploadLimit:
    """ASGI middleware: refuse a request body larger than ``max_bytes`` on ``POST /v1/sessions`` (413),
    from its Content-Length before reading it, or while it streams when the length is not declared."""

    def __init__(self, app, max_bytes: int, overhead: int = 64 * 1024):
        self.app, self.max_bytes, self.overhead = app, int(max_bytes), overhead

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or scope["method"] != "POST" or not scope["path"].rstrip("/").endswith("/sessions"):
            return await self.app(scope, receive, send)
        limit = self.max_bytes + self.overhead  # multipart framing around the file
        headers = dict(scope.get("headers") or [])
        declared = headers.get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > limit:
            return await self._refuse(send, int(declared))
        seen = 0
        exceeded = False
        replaced = False

        async def counted_receive():
            nonlocal seen, exceeded
            msg = await receive()
            if msg["type"] == "http.request":
                seen += len(msg.get("body", b""))
                if seen > limit:
                    exceeded = True
                    raise _TooLarge(f"request body over {limit} bytes")
            return msg

        async def guarded_send(msg):
            # the body parser turns our exception into some error response: answer 413 instead
            nonlocal replaced
            if exceeded:
                if msg["type"] == "http.response.start" and not replaced:
                    replaced = True
                    await self._refuse(send, seen)
                return
            await send(msg)

        try:
            await self.app(scope, counted_receive, guarded_send)
        except _TooLarge:
            if not replaced:
                await self._refuse(send, seen)

    async def _refuse(self, send, size: int) -> None:
        body = problems.problem_bytes(413, "Upload too large",
                                      f"upload: {size} bytes or more, the limit is {self.max_bytes} bytes "
                                      "(VYSICS_LIMIT_MAX_UPLOAD_BYTES)", "upload-too-large")
        await send({"type": "http.response.start", "status": 413,
                    "headers": [(b"content-type", b"application/problem+json"),
                                (b"content-length", str(len(body)).encode()), (b"connection", b"close")]})
        await send({"type": "http.response.body", "body": body})


class _TooLarge(Exception):
    pass


def get_jobs(request: Request) -> J.JobStore:
    return request.app.state.jobs


Jobs = Annotated[J.JobStore, Depends(get_jobs)]


def _links(request: Request, job_id: str) -> Links:
    base = str(request.base_url).rstrip("/")
    return Links(self=f"{base}/v1/sessions/{job_id}", bundle=f"{base}/v1/sessions/{job_id}/bundle",
                 report=f"{base}/v1/sessions/{job_id}/report")


def _save_upload(upload: UploadFile, folder: Path, max_bytes: int) -> tuple[Path, str, int]:
    """Copy the upload to ``folder/<its safe file name>`` hashing it; 413 beyond ``max_bytes``."""
    name = SAFE_NAME.sub("_", Path(upload.filename or "session.zip").name).strip("._") or "session.zip"
    dst = folder / name
    h = hashlib.sha256()
    n = 0
    with open(dst, "wb") as out:
        while chunk := upload.file.read(CHUNK):
            n += len(chunk)
            if n > max_bytes:
                raise ApiProblem(413, "Upload too large",
                                 f"{name}: more than {max_bytes} bytes (VYSICS_LIMIT_MAX_UPLOAD_BYTES)",
                                 kind="upload-too-large", file=name, rule=f"at most {max_bytes} bytes")
            h.update(chunk)
            out.write(chunk)
    if n == 0:
        raise ApiProblem(422, "Invalid session", f"{name}: empty upload", kind="invalid-session", file=name,
                         rule="empty upload")
    return dst, h.hexdigest(), n


def create_app(settings: ApiSettings | None = None, *, launcher: Launcher | None = None) -> FastAPI:
    settings = settings or ApiSettings()
    launcher = launcher or make_launcher(settings)
    jobs = J.JobStore(settings.jobs_dir)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        for d in (settings.uploads_dir, settings.sessions_dir, settings.jobs_dir, settings.artifacts_dir):
            d.mkdir(parents=True, exist_ok=True)
        launcher.start()
        yield
        launcher.close()

    app = FastAPI(
        title="Vysics",
        version=service.__version__,
        description="Simulation-ready object models (URDF, meshes, inertia, friction) and a metric report from "
                    "short RGBD robot-interaction sessions (session format vysics-session/1, bundle vysics-bundle/1).",
        lifespan=lifespan,
    )
    app.state.settings = settings
    app.state.launcher = launcher
    app.state.jobs = jobs
    problems.install(app)
    app.add_middleware(UploadLimit, max_bytes=settings.limits.max_upload_bytes)

    def job_or_404(job_id: str, jobs: J.JobStore) -> dict:
        job = jobs.get(job_id) if re.fullmatch(r"[0-9a-f]{64}", job_id) else None
        if job is None:
            raise ApiProblem(404, "Not found", f"no session with id {job_id!r}", kind="not-found")
        return job

    @app.get("/healthz", response_model=Health, tags=["service"])
    def healthz() -> Health:
        return Health(status="ok", version=service.__version__, launcher=settings.launcher)

    @app.post("/v1/sessions", status_code=202, response_model=SessionAccepted, tags=["sessions"],
              responses={k: PROBLEM_RESPONSES[k] for k in (413, 422)})
    async def create_session(request: Request, jobs: Jobs,
                             file: Annotated[UploadFile, File(description="session archive: .zip, .tar, .tar.gz or .tgz")]):
        """Upload a session archive (vysics-session/1). It is validated before anything is stored."""
        settings.uploads_dir.mkdir(parents=True, exist_ok=True)
        folder = settings.uploads_dir / f"upload-{uuid.uuid4().hex}"
        folder.mkdir()
        try:
            path, sha, _ = await run_in_threadpool(_save_upload, file, folder, settings.limits.max_upload_bytes)
            from flows.sessions import store_upload

            _, st = await run_in_threadpool(store_upload, path, settings.data_dir, sha=sha, limits=settings.limits)
        finally:
            shutil.rmtree(folder, ignore_errors=True)
            await file.close()
        job, created = jobs.create(J.new_job(sha, session_sha256=sha, name=st.name, frames=st.frames,
                                             preset=settings.preset))
        if created:
            jobs.stage(sha, "ingest", state=J.COMPLETED, fraction=1.0, seconds=st.ingest_seconds, cached=st.reused,
                       message="validated and stored")
            launcher.submit(sha, sha)
        log.info("session %s upload: %s job (%s)", sha[:12], "new" if created else "existing", job["state"])
        return SessionAccepted(id=sha, state=job["state"], created=created,
                               session=SessionInfo(sha256=sha, name=st.name, frames=st.frames),
                               links=_links(request, sha))

    @app.get("/v1/sessions/{session_id}", response_model=SessionStatus, tags=["sessions"],
             responses={404: PROBLEM_RESPONSES[404]})
    def get_session(session_id: str, request: Request, jobs: Jobs) -> SessionStatus:
        """The job's state, every stage's progress and, on failure, the stage and the reason."""
        job = job_or_404(session_id, jobs)
        return SessionStatus(
            id=job["id"], state=job["state"], session=SessionInfo(**job["session"]), preset=job.get("preset"),
            stages=job["stages"], error=job.get("error"), warnings=job.get("warnings") or [],
            created=job.get("created"), updated=job.get("updated"),
            started=job.get("started"), finished=job.get("finished"), links=_links(request, job["id"]))

    def _ready(job: dict) -> Path:
        if job["state"] == J.FAILED:
            err = job.get("error") or {}
            raise ApiProblem(409, "Processing failed", f"{err.get('stage')}: {err.get('reason')}",
                             kind="stage-failed", stage=err.get("stage"))
        if job["state"] != J.COMPLETED or not job.get("bundle") or not Path(job["bundle"]).is_file():
            raise ApiProblem(409, "Not ready", f"the bundle of {job['id']} is not ready (state {job['state']})",
                             kind="not-ready")
        return Path(job["bundle"])

    @app.get("/v1/sessions/{session_id}/bundle", tags=["sessions"], response_class=FileResponse,
             responses={200: {"content": {"application/zip": {}}, "description": "the result bundle"},
                        404: PROBLEM_RESPONSES[404], 409: PROBLEM_RESPONSES[409]})
    def get_bundle(session_id: str, jobs: Jobs):
        """The result bundle (vysics-bundle/1) as a zip."""
        job = job_or_404(session_id, jobs)
        zip_path = _ready(job)
        name = SAFE_NAME.sub("_", (job.get("session") or {}).get("name") or session_id[:12])
        return FileResponse(zip_path, media_type="application/zip", filename=f"{name}-bundle.zip")

    @app.get("/v1/sessions/{session_id}/report", tags=["sessions"],
             responses={200: {"content": {"application/json": {}}, "description": "report.json"},
                        404: PROBLEM_RESPONSES[404], 409: PROBLEM_RESPONSES[409]})
    def get_report(session_id: str, jobs: Jobs):
        """``report.json`` of the bundle (format vysics-report/1)."""
        job = job_or_404(session_id, jobs)
        zip_path = _ready(job)
        report = zip_path.parent / "bundle" / "report.json"
        if not report.is_file():
            raise ApiProblem(409, "Not ready", f"no report for {session_id}", kind="not-ready")
        import json

        return JSONResponse(json.loads(report.read_text()))

    return app
