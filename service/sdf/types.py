"""A dense signed-distance grid in the object frame O (metres), trilinearly interpolated."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SdfGrid:
    origin_O: np.ndarray  # (3,) position of voxel (0,0,0) centre in O, m
    voxel: float  # voxel edge, m
    values: np.ndarray  # (nx,ny,nz) float32 signed distance, m (positive outside)
    observed: np.ndarray | None = None  # (nx,ny,nz) bool: voxel had direct supervision
