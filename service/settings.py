"""Service settings, read from environment variables prefixed ``VYSICS_``.

``VYSICS_DATA_DIR``: where uploads and artifacts live (default ``./vysics-data``).
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict


class Limits(BaseSettings):
    """Limits applied to uploaded archives before anything is unpacked or stored."""

    model_config = SettingsConfigDict(env_prefix="VYSICS_LIMIT_", extra="ignore")

    max_upload_bytes: int = Field(2 * 1024**3, description="size of the uploaded archive")
    max_unpacked_bytes: int = Field(8 * 1024**3, description="sum of the members' sizes")
    max_entries: int = Field(20_000, description="number of archive members")
    max_compression_ratio: float = Field(200.0, description="unpacked / packed size, per archive")
    max_frames: int = Field(3_000, description="frames per session")
    max_width: int = Field(1920)
    max_height: int = Field(1200)


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="VYSICS_", extra="ignore")

    data_dir: Path = Field(Path("vysics-data"), description="uploads, sessions and artifacts")
    api_host: str = "127.0.0.1"
    api_port: int = 8000
    preset: str = Field("default", description="pipeline configuration preset: default | fast")
    log_level: str = "INFO"

    @property
    def limits(self) -> Limits:
        return Limits()

    @property
    def uploads_dir(self) -> Path:
        return self.data_dir / "uploads"

    @property
    def sessions_dir(self) -> Path:
        return self.data_dir / "sessions"

    @property
    def artifacts_dir(self) -> Path:
        return self.data_dir / "artifacts"

    @property
    def jobs_dir(self) -> Path:
        return self.data_dir / "jobs"


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    return Settings()
