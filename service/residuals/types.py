"""Inputs and outputs of the residual loop (find the missing effect, add it, measure before/after)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class ResidualConfig:
    """Settings of the residual loop. ``fast()`` is the reduced preset used by tests."""

    seed: int = 0

    @classmethod
    def fast(cls) -> "ResidualConfig":
        return cls()


@dataclass(frozen=True)
class EffectCandidate:
    effect: str  # e.g. "restitution"
    params: dict[str, float]
    heldout_error_before: float
    heldout_error_after: float
    accepted: bool
    reason: str = ""


@dataclass(frozen=True)
class ResidualOutputs:
    candidates: tuple[EffectCandidate, ...]
    accepted: tuple[str, ...]
    effects: dict[str, float]  # parameters of accepted effects, go into ObjectModel.effects
    error_before: dict[str, float]  # {"pos_err_m":…, "rot_err_deg":…}
    error_after: dict[str, float]
    by_mode: dict = field(default_factory=dict)  # residual statistics split by contact mode
