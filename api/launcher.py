"""Starting jobs without blocking requests.

``LocalLauncher`` (default) keeps one runner process (``python -m workers.runner``) next to the API: it
takes queued jobs from ``<data_dir>/jobs`` one at a time and runs the Prefect flow ``process-session``.
The API process itself never imports the science code (nor torch). ``PrefectLauncher`` asks a Prefect
server to run the ``process-session`` deployment that ``vysics worker`` serves (docker compose).
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import threading
from pathlib import Path

from api.settings import ApiSettings

log = logging.getLogger("vysics.api")


class Launcher:
    def submit(self, job_id: str, sha256: str) -> None:  # pragma: no cover - interface
        raise NotImplementedError

    def start(self) -> None:
        pass

    def close(self) -> None:
        pass


class NoLauncher(Launcher):
    """Queue only (jobs stay queued until a runner takes them)."""

    def submit(self, job_id: str, sha256: str) -> None:
        log.info("job %s queued (no launcher)", job_id[:12])


class LocalLauncher(Launcher):
    def __init__(self, settings: ApiSettings):
        self.settings = settings
        self.proc: subprocess.Popen | None = None
        self.lock = threading.Lock()

    def _alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def ensure_runner(self) -> None:
        with self.lock:
            if self._alive():
                return
            data_dir = Path(self.settings.data_dir).resolve()
            logs = data_dir / "logs"
            logs.mkdir(parents=True, exist_ok=True)
            env = dict(os.environ, VYSICS_DATA_DIR=str(data_dir), VYSICS_PRESET=self.settings.preset)
            cmd = [sys.executable, "-m", "workers.runner", "--data-dir", str(data_dir),
                   "--parent-pid", str(os.getpid()), "--poll", str(self.settings.runner_poll_s)]
            with open(logs / "runner.log", "ab") as out:
                self.proc = subprocess.Popen(cmd, env=env, stdout=out, stderr=subprocess.STDOUT,
                                             stdin=subprocess.DEVNULL, start_new_session=True)
            log.info("runner process %d started (log: %s)", self.proc.pid, logs / "runner.log")

    def start(self) -> None:
        from flows.jobs import JobStore

        jobs = JobStore(self.settings.jobs_dir)
        if any(j.get("state") in ("queued", "running") for j in jobs.list()):
            self.ensure_runner()

    def submit(self, job_id: str, sha256: str) -> None:
        self.ensure_runner()

    def close(self) -> None:
        with self.lock:
            if self._alive():
                self.proc.terminate()
                try:
                    self.proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait()
            self.proc = None


class PrefectLauncher(Launcher):
    """Create a flow run of the served deployment; the worker process does the work."""

    def __init__(self, settings: ApiSettings):
        self.settings = settings

    def submit(self, job_id: str, sha256: str) -> None:
        def go() -> None:
            from prefect.deployments import run_deployment

            try:
                fr = run_deployment(name=self.settings.deployment, parameters={"session": sha256, "job_id": job_id},
                                    timeout=0)
                log.info("job %s: flow run %s created", job_id[:12], getattr(fr, "id", "?"))
            except Exception as e:  # noqa: BLE001 - report into the job, the request has been answered
                from flows.jobs import JobStore

                log.exception("job %s: could not create the flow run", job_id[:12])
                JobStore(self.settings.jobs_dir).fail(job_id, "orchestration", f"{type(e).__name__}: {e}")

        threading.Thread(target=go, name=f"submit-{job_id[:8]}", daemon=True).start()


def make_launcher(settings: ApiSettings) -> Launcher:
    if settings.launcher == "local":
        return LocalLauncher(settings)
    if settings.launcher == "prefect":
        return PrefectLauncher(settings)
    return NoLauncher()
