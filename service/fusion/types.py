"""Inputs and outputs of the fusion stage (second SDF pass with physible supervision)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.mesh import Mesh
from service.sdf.types import SdfGrid
from service.session.types import Session


@dataclass(frozen=True)
class FusionInputs:
    session: Session
    X_WO: np.ndarray  # (N,4,4) tracked poses
    tracked: np.ndarray  # (N,) bool
    visible_sdf: SdfGrid  # warm start / grid extent
    physible_points_O: np.ndarray  # (P,3)
    physible_normals_O: np.ndarray  # (P,3)
    physible_mesh: Mesh


@dataclass(frozen=True)
class FusionOutputs:
    sdf: SdfGrid
    mesh: Mesh  # watertight, frame O


@dataclass(frozen=True)
class FusionConfig:
    """Settings of the fusion SDF pass. ``fast()`` is the reduced preset used by tests."""

    seed: int = 0

    @classmethod
    def fast(cls) -> "FusionConfig":
        return cls()
