"""Inputs and outputs of evaluation (the only stage that reads ground_truth/)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from service.mesh import Mesh
from service.model import ObjectModel
from service.session.types import Session
from service.sim.types import SimConfig

METHODS: tuple[str, ...] = ("vision_only", "physics_only", "fused")


@dataclass(frozen=True)
class EvaluationConfig:
    """Settings of evaluation (method-notes §8). ``fast()`` is the reduced preset used by tests."""

    seed: int = 0
    n_samples: int = 2000  # surface samples per mesh for chamfer
    icp_max_corr: float = 0.02  # m
    icp_max_iter: int = 2000
    iou_pitch: float = 0.002  # m, finest voxel
    iou_max_res: int = 128  # voxels along the longest side of the union box
    div_pos_m: float = 0.10  # divergence thresholds
    div_rot_deg: float = 45.0
    sim: SimConfig = field(default_factory=SimConfig)
    robot_mode: str = "auto"  # "auto": impedance toward cmd_* when recorded, else kinematic replay
    initial_velocity: str = "finite_difference"  # or "zero"
    rest_translation_m: float = 0.002  # first-frame motion below both is tracking noise: start at rest
    rest_rotation_deg: float = 1.0
    collision: str = "decompose"  # pieces for a model without any: "decompose" (as the bundle's URDF) | "hull"
    geometry: bool = True
    dynamics: bool = True

    @classmethod
    def fast(cls) -> "EvaluationConfig":
        return cls(n_samples=800, icp_max_iter=60, iou_pitch=0.003, iou_max_res=64, sim=SimConfig.fast(), collision="hull")


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
