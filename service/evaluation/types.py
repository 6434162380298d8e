"""Inputs and outputs of evaluation (the only stage that reads ground_truth/)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from service.mesh import Mesh
from service.model import ObjectModel
from service.session.types import Session


@dataclass(frozen=True)
class EvaluationConfig:
    """Settings of evaluation. ``fast()`` is the reduced preset used by tests."""

    seed: int = 0

    @classmethod
    def fast(cls) -> "EvaluationConfig":
        return cls()


@dataclass(frozen=True)
class EvaluationInputs:
    session: Session
    t: np.ndarray  # (N,) frame times
    X_WO: np.ndarray  # (N,4,4) tracked poses
    tracked: np.ndarray  # (N,) bool
    meshes: dict[str, Mesh]  # "vision_only", "physics_only", "fused" in O
    models: dict[str, ObjectModel]  # same keys: the model simulated for each method


@dataclass(frozen=True)
class EvaluationOutputs:
    tracking: dict  # report.json "tracking.vs_ground_truth" (or None values with reasons)
    geometry: dict  # report.json "geometry"
    dynamics: dict  # report.json "dynamics"
    series: dict[str, np.ndarray] = field(default_factory=dict)  # curves for plots
