"""Inputs and outputs of the tracking and visible-geometry stage."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.mesh import Mesh
from service.sdf.types import SdfGrid
from service.session.types import Session


@dataclass(frozen=True)
class TrackingInputs:
    session: Session


@dataclass(frozen=True)
class TrackingOutputs:
    t: np.ndarray  # (N,) frame times, s
    X_WO: np.ndarray  # (N,4,4) object pose per frame
    tracked: np.ndarray  # (N,) bool: False where the track was lost (pose interpolated/held)
    v_WO_W: np.ndarray  # (N,3) velocity of O's origin in W, filtered backward differences, m/s
    w_WO_O: np.ndarray  # (N,3) angular velocity in O (body) axes, rad/s
    sdf: SdfGrid  # visible-geometry SDF in O
    visible_mesh: Mesh  # marching cubes of sdf, frame O
    visible_points_O: np.ndarray  # (K,3) the visible set V (hull points that pass the visibility check)
    frames_lost: int


@dataclass(frozen=True)
class TrackingConfig:
    """Settings of tracking and the visible-geometry SDF. ``fast()`` is the reduced preset used by tests."""

    seed: int = 0

    @classmethod
    def fast(cls) -> "TrackingConfig":
        return cls()
