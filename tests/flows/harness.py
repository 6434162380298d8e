"""Test helpers shared by the API and command-line tests: one Prefect API for the whole test run.

``use_test_prefect_home()`` must run before prefect is imported (the conftests call it at import): Prefect's
database goes to a temporary folder, telemetry off. ``prefect_api()`` starts Prefect's embedded API server
once per test process (the very server a flow run starts by itself when ``PREFECT_API_URL`` is unset) and
exports its URL, so runner processes started by the API under test use it instead of starting their own.
"""

from __future__ import annotations

import os
import socket
import tempfile
from pathlib import Path

_SERVER = None


def use_test_prefect_home() -> None:
    # One home (database) per test process: parallel workers (pytest-xdist) must not share a SQLite file.
    key = "VYSICS_TEST_PREFECT_HOME_" + os.environ.get("PYTEST_XDIST_WORKER", "main")
    if key not in os.environ:
        home = tempfile.mkdtemp(prefix="vysics-test-prefect-")
        os.environ[key] = home
        os.environ["PREFECT_HOME"] = home
    from flows.runtime import configure_prefect

    configure_prefect(Path(os.environ[key]).parent)


def prefect_api() -> str:
    global _SERVER
    if _SERVER is None:
        from prefect.server.api.server import SubprocessASGIServer

        srv = SubprocessASGIServer()  # the process-wide instance flow runs use when no API URL is set
        srv.start(timeout=600)
        _SERVER = srv
        os.environ["PREFECT_API_URL"] = srv.api_url
    return _SERVER.api_url


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def tiny_session(folder: Path, *, frames: int = 6, seed: int = 0) -> Path:
    """A small valid session folder from the project's synthetic lab."""
    from service.synth import SynthSpec, make_session

    return make_session(SynthSpec(preset="tiny", n_frames=frames, seed=seed), Path(folder)).session_dir


def stop_prefect_api() -> None:
    global _SERVER
    if _SERVER is not None:
        try:  # ship pending run logs while the API still listens
            from prefect.logging.handlers import APILogWorker

            APILogWorker.drain_all(timeout=30)
        except Exception:  # noqa: BLE001 - best effort at the end of the test run
            pass
        _SERVER.stop()
        _SERVER = None


try:
    import pytest

    @pytest.fixture(scope="session")
    def prefect_server():
        """The Prefect API of the test run (started once, stopped at the end of the run)."""
        url = prefect_api()
        yield url
        stop_prefect_api()
except ImportError:  # pragma: no cover
    pass
