"""Typed domain errors. The API maps them to problem+json; the CLI prints them."""

from __future__ import annotations


class VysicsError(Exception):
    """Base class of every error the service raises on purpose."""


class InvalidSession(VysicsError):
    """An uploaded session breaks a rule of the session format (HTTP 422).

    ``file`` is the member path inside the session (e.g. ``depth/000041.png``) or the archive name;
    ``rule`` says which rule it breaks, in words a lab engineer can act on.
    """

    def __init__(self, file: str, rule: str):
        self.file = file
        self.rule = rule
        super().__init__(f"{file}: {rule}")


class InvalidInput(VysicsError):
    """Bad input that is not a session archive (e.g. a trajectory .npz for fit-dynamics)."""

    def __init__(self, file: str, rule: str):
        self.file = file
        self.rule = rule
        super().__init__(f"{file}: {rule}")


class StageFailed(VysicsError):
    """A science stage could not produce its output (the job fails with this stage and reason)."""

    def __init__(self, stage: str, reason: str):
        self.stage = stage
        self.reason = reason
        super().__init__(f"{stage}: {reason}")


class NotFound(VysicsError):
    """A session id or artifact that does not exist (HTTP 404)."""
