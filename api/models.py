"""Request and response models of the HTTP API (what OpenAPI documents)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

JobState = Literal["queued", "running", "completed", "failed"]
StageState = Literal["pending", "running", "completed", "failed", "skipped"]


class Links(BaseModel):
    self: str = Field(description="status of this session's job")
    bundle: str = Field(description="result bundle (.zip), once completed")
    report: str = Field(description="report.json, once completed")


class SessionInfo(BaseModel):
    sha256: str
    name: str | None = None
    frames: int | None = None


class SessionAccepted(BaseModel):
    """Answer to an upload: the session's id (sha256 of the uploaded bytes) and its job's state."""

    id: str
    state: JobState
    created: bool = Field(description="False when the same bytes were uploaded before (the job is not restarted)")
    session: SessionInfo
    links: Links


class StageStatus(BaseModel):
    state: StageState
    fraction: float = Field(ge=0.0, le=1.0)
    message: str = ""
    cached: bool = False
    seconds: float | None = None


class ErrorInfo(BaseModel):
    stage: str
    reason: str


class SessionStatus(BaseModel):
    id: str
    state: JobState
    session: SessionInfo
    preset: str | None = None
    stages: dict[str, StageStatus]
    error: ErrorInfo | None = None
    warnings: list[ErrorInfo] = Field(default_factory=list,
                                      description="measuring stages that failed without failing the job")
    created: str | None = None
    updated: str | None = None
    started: str | None = None
    finished: str | None = None
    links: Links


class Health(BaseModel):
    status: Literal["ok"]
    version: str
    launcher: str


class Problem(BaseModel):
    """RFC 9457 problem details (``application/problem+json``)."""

    type: str = "about:blank"
    title: str
    status: int
    detail: str
    file: str | None = Field(None, description="for invalid sessions: the file that breaks a rule")
    rule: str | None = Field(None, description="for invalid sessions: the rule it breaks")
    stage: str | None = None
