"""The local job runner: takes queued jobs from ``<data_dir>/jobs`` one at a time and runs the flow.

Started by the API (``VYSICS_LAUNCHER=local``) as ``python -m workers.runner --data-dir D --parent-pid P``;
it exits when its parent is gone. One process runs the jobs sequentially (the science stages use every
core), and one embedded Prefect API serves all its flow runs. Jobs left ``running`` by a dead runner are
queued again at start.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from pathlib import Path

log = logging.getLogger("vysics.runner")


def _parent_alive(pid: int | None) -> bool:
    if not pid:
        return True
    if os.getppid() != pid:
        return False
    try:
        os.kill(pid, 0)
        return True
    except ProcessLookupError:
        return False
    except PermissionError:
        return True


def run_queue(data_dir: Path, *, parent_pid: int | None = None, poll_s: float = 0.5, once: bool = False) -> int:
    """Process queued jobs until the parent exits (or, with ``once``, until the queue is empty)."""
    from flows.runtime import configure_prefect

    configure_prefect(data_dir)
    from flows.jobs import JobStore
    from flows.pipeline import process_session

    jobs = JobStore(Path(data_dir) / "jobs")
    back = jobs.requeue_orphans()
    if back:
        log.info("requeued %d jobs of a runner that stopped", len(back))
    me = f"pid:{os.getpid()}"
    done = 0
    while _parent_alive(parent_pid):
        job_id = jobs.next_queued()
        if job_id is None:
            if once:
                break
            time.sleep(poll_s)
            continue
        if not jobs.claim(job_id, me):
            continue
        job = jobs.get(job_id)
        log.info("session %s: job started", job_id[:12])
        try:
            process_session(session=job["session"]["sha256"], data_dir=str(data_dir), preset=job.get("preset"),
                            config=job.get("config"), job_id=job_id)
            log.info("session %s: job completed", job_id[:12])
        except Exception as e:  # noqa: BLE001 - the job state holds stage and reason; keep serving
            log.error("session %s: job failed: %s", job_id[:12], e)
            j = jobs.get(job_id)
            if j is not None and j["state"] == "running":  # failed before the flow could record it
                jobs.fail(job_id, "orchestration", f"{type(e).__name__}: {e}")
        done += 1
    return done


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m workers.runner", description=__doc__.splitlines()[0])
    p.add_argument("--data-dir", required=True, type=Path)
    p.add_argument("--parent-pid", type=int, default=None)
    p.add_argument("--poll", type=float, default=0.5)
    p.add_argument("--once", action="store_true", help="exit when the queue is empty")
    a = p.parse_args(argv)
    logging.basicConfig(level=os.environ.get("VYSICS_LOG_LEVEL", "INFO"),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    logging.getLogger("httpx").setLevel(logging.WARNING)
    run_queue(a.data_dir.resolve(), parent_pid=a.parent_pid, poll_s=a.poll, once=a.once)
    return 0


if __name__ == "__main__":
    sys.exit(main())
