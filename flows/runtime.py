"""Prefect runtime defaults, applied before prefect is first imported.

Without ``PREFECT_API_URL`` Prefect runs flows against its embedded (ephemeral) API on SQLite; its
database then lives in ``PREFECT_HOME``, which defaults here to ``<VYSICS_DATA_DIR>/prefect``. Telemetry
is off (the service must work with no network) and the embedded server gets a generous start-up
timeout (a loaded 2-core machine needs it). Variables already set by the user are left alone.
"""

from __future__ import annotations

import os
from pathlib import Path


def configure_prefect(data_dir: Path | str | None = None) -> None:
    if data_dir is None:
        data_dir = os.environ.get("VYSICS_DATA_DIR", "vysics-data")
    home = Path(data_dir).resolve() / "prefect"
    os.environ.setdefault("PREFECT_HOME", str(home))
    Path(os.environ["PREFECT_HOME"]).expanduser().mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "180")
    os.environ.setdefault("PREFECT_LOGGING_LEVEL", os.environ.get("VYSICS_LOG_LEVEL", "INFO"))
    os.environ.setdefault("PREFECT_UI_ENABLED", "false")
