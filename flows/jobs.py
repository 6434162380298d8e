"""Job state on disk: ``<data_dir>/jobs/<id>.json``, readable by any process (API, runner, CLI).

A job is one processing of one stored session. Its id is the session's sha256 (the same bytes uploaded
twice give the same job). States: ``queued`` -> ``running`` -> ``completed`` | ``failed``. Every stage has
``{state, fraction, message, cached, seconds}``; a failed job has ``error = {stage, reason}`` (the traceback
goes to the log only). Writes are atomic (temporary file + ``os.replace``) under a per-job ``flock``, so
readers never see half a file and concurrent writers do not lose updates.

Plain Python: importing this module imports neither prefect nor torch (the API reads jobs through it).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

QUEUED, RUNNING, COMPLETED, FAILED = "queued", "running", "completed", "failed"
STATES = (QUEUED, RUNNING, COMPLETED, FAILED)
STAGE_ORDER = ("ingest", "tracking", "contact", "fusion", "evaluation", "residuals", "bundle")
PENDING, SKIPPED = "pending", "skipped"


def now_iso() -> str:
    t = time.time()
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(t)) + f".{int(t * 1000) % 1000:03d}Z"


def _valid_id(job_id: str) -> str:
    if not job_id or len(job_id) > 128 or any(not (c.isalnum() or c in "-_") for c in job_id):
        raise ValueError(f"invalid job id {job_id!r}")
    return job_id


def new_job(job_id: str, *, session_sha256: str, name: str | None, frames: int | None, preset: str,
            config: dict | None = None) -> dict:
    return {
        "id": job_id,
        "state": QUEUED,
        "session": {"sha256": session_sha256, "name": name, "frames": frames},
        "preset": preset,
        "config": config,
        "stages": {s: {"state": PENDING, "fraction": 0.0, "message": "", "cached": False, "seconds": None}
                   for s in STAGE_ORDER},
        "error": None,
        "warnings": [],  # failures of measuring stages (evaluation, residuals) that did not fail the job
        "bundle": None,
        "runner": None,
        "created": now_iso(),
        "updated": now_iso(),
        "started": None,
        "finished": None,
        "attempts": 0,
    }


class JobStore:
    """Jobs under ``jobs_dir``; every mutation goes through :meth:`update` (locked read-modify-write)."""

    def __init__(self, jobs_dir: Path):
        self.dir = Path(jobs_dir)

    def path(self, job_id: str) -> Path:
        return self.dir / f"{_valid_id(job_id)}.json"

    @contextlib.contextmanager
    def _lock(self, job_id: str) -> Iterator[None]:
        self.dir.mkdir(parents=True, exist_ok=True)
        with open(self.dir / f".{_valid_id(job_id)}.lock", "a+") as fh:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(fh.fileno(), fcntl.LOCK_UN)

    def _write(self, job: dict) -> None:
        p = self.path(job["id"])
        tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps(job, indent=1, allow_nan=False, default=str))
        os.replace(tmp, p)

    def get(self, job_id: str) -> dict | None:
        try:
            return json.loads(self.path(job_id).read_text())
        except FileNotFoundError:
            return None
        except ValueError:  # invalid id
            return None

    def exists(self, job_id: str) -> bool:
        try:
            return self.path(job_id).is_file()
        except ValueError:
            return False

    def create(self, job: dict, *, requeue_failed: bool = True) -> tuple[dict, bool]:
        """Store ``job`` unless one with its id exists. Returns ``(job, created)``.

        An existing failed job is queued again when ``requeue_failed`` (the code may have been fixed);
        queued, running and completed jobs are returned as they are."""
        with self._lock(job["id"]):
            old = self.get(job["id"])
            if old is not None:
                if requeue_failed and old["state"] == FAILED:
                    fresh = dict(job, created=old["created"], attempts=old.get("attempts", 0))
                    self._write(fresh)
                    return fresh, True
                return old, False
            self._write(job)
            return job, True

    def put(self, job: dict) -> None:
        """Replace a job unconditionally (command-line runs that own their job)."""
        with self._lock(job["id"]):
            job["updated"] = now_iso()
            self._write(job)

    def update(self, job_id: str, fn: Callable[[dict], Any]) -> dict:
        """Apply ``fn(job)`` (in place) under the job's lock and write the result atomically."""
        with self._lock(job_id):
            job = self.get(job_id)
            if job is None:
                raise KeyError(job_id)
            fn(job)
            job["updated"] = now_iso()
            self._write(job)
            return job

    def list(self) -> list[dict]:
        if not self.dir.is_dir():
            return []
        out = []
        for p in sorted(self.dir.glob("*.json")):
            try:
                out.append(json.loads(p.read_text()))
            except (OSError, ValueError):
                continue
        return out

    # ------------------------------------------------------------------ transitions
    def claim(self, job_id: str, runner: str) -> bool:
        """queued -> running for ``runner`` (a process id or a flow-run id); False if someone else has it."""
        claimed = False

        def fn(job: dict) -> None:
            nonlocal claimed
            if job["state"] == QUEUED:
                job["state"] = RUNNING
                job["runner"] = runner
                job["started"] = now_iso()
                job["attempts"] = job.get("attempts", 0) + 1
                claimed = True

        self.update(job_id, fn)
        return claimed

    def next_queued(self) -> str | None:
        queued = [j for j in self.list() if j.get("state") == QUEUED]
        queued.sort(key=lambda j: j.get("created") or "")
        return queued[0]["id"] if queued else None

    def requeue_orphans(self) -> list[str]:
        """Running jobs whose runner process (``pid:<n>``) is gone go back to queued."""
        back = []
        for job in self.list():
            r = job.get("runner") or ""
            if job.get("state") != RUNNING or not r.startswith("pid:"):
                continue
            try:
                os.kill(int(r[4:]), 0)
                continue
            except ProcessLookupError:
                pass
            except (PermissionError, ValueError):
                continue

            def fn(j: dict) -> None:
                if j["state"] == RUNNING and j.get("runner") == r:
                    j["state"] = QUEUED
                    j["runner"] = None

            self.update(job["id"], fn)
            back.append(job["id"])
        return back

    def stage(self, job_id: str, stage: str, **fields: Any) -> dict:
        def fn(job: dict) -> None:
            job["stages"].setdefault(stage, {"state": PENDING, "fraction": 0.0, "message": "", "cached": False,
                                             "seconds": None}).update(fields)

        return self.update(job_id, fn)

    def finish(self, job_id: str, *, bundle: str | None) -> dict:
        def fn(job: dict) -> None:
            job["state"] = COMPLETED
            job["bundle"] = bundle
            job["error"] = None
            job["finished"] = now_iso()

        return self.update(job_id, fn)

    def fail(self, job_id: str, stage: str, reason: str) -> dict:
        def fn(job: dict) -> None:
            job["state"] = FAILED
            job["error"] = {"stage": stage, "reason": reason}
            job["finished"] = now_iso()
            st = job["stages"].get(stage)
            if st is not None:
                st["state"] = FAILED

        return self.update(job_id, fn)


class ProgressBridge:
    """``progress(fraction, message)`` for one stage of one job: writes the job state (throttled) and
    forwards to ``also`` (e.g. a Prefect progress artifact). Fractions are clipped to [0, 1]."""

    def __init__(self, jobs: JobStore | None, job_id: str | None, stage: str, *, min_interval_s: float = 0.25,
                 also: Callable[[float, str], None] | None = None):
        self.jobs, self.job_id, self.stage = jobs, job_id, stage
        self.min_interval_s = min_interval_s
        self.also = also
        self._last: float | None = None
        self.fraction = 0.0
        self.message = ""

    def __call__(self, fraction: float, message: str = "") -> None:
        f = float(fraction)
        f = 0.0 if f != f else min(max(f, 0.0), 1.0)
        self.fraction, self.message = f, str(message)
        now = time.monotonic()
        if f < 1.0 and self._last is not None and now - self._last < self.min_interval_s:
            return
        self._last = now
        if self.jobs is not None and self.job_id is not None:
            try:
                self.jobs.stage(self.job_id, self.stage, fraction=f, message=self.message)
            except (OSError, KeyError):
                pass  # progress is best effort; the stage result is what counts
        if self.also is not None:
            try:
                self.also(f, self.message)
            except Exception:  # noqa: BLE001 - a progress sink must never break a stage
                pass
