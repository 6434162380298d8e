"""The simulation-ready object model that the bundle's URDF describes (frame O, SI units)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from service.mesh import Mesh
from service.session.types import Friction


@dataclass(frozen=True)
class ObjectModel:
    visual: Mesh  # watertight geometry in O (the fused mesh in the final model)
    collision: tuple[Mesh, ...]  # convex pieces in O
    mass: float  # kg
    mass_declared: bool  # False when a default mass was used
    com_O: np.ndarray  # (3,) centre of mass in O, m
    inertia_O: np.ndarray  # (3,3) rotational inertia about the CoM, axes of O, kg m^2
    friction: Friction
    effects: dict[str, float] = field(default_factory=dict)  # accepted effects, e.g. {"restitution": 0.4}
