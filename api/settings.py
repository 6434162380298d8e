"""API settings: the service settings (``VYSICS_*``) plus how jobs are launched.

``VYSICS_LAUNCHER``: ``local`` (default) starts one runner process next to the API that takes queued jobs
from ``<data_dir>/jobs`` and runs the Prefect flow (embedded Prefect API unless ``PREFECT_API_URL`` is set);
``prefect`` asks a Prefect server to run the ``process-session`` deployment served by ``vysics worker``
(docker compose).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field
from pydantic_settings import SettingsConfigDict

from service.settings import Settings


class ApiSettings(Settings):
    model_config = SettingsConfigDict(env_prefix="VYSICS_", extra="ignore")

    launcher: Literal["local", "prefect", "none"] = Field(
        "local", description="local: runner process next to the API; prefect: run the deployment; none: queue only")
    deployment: str = Field("process-session/process-session", description="flow/deployment name (launcher=prefect)")
    runner_poll_s: float = Field(0.5, description="how often the local runner looks for queued jobs")
