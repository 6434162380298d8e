"""Residual-loop inputs for object trajectories without video (the ``fit-dynamics`` path).

``states[k]`` is (T_k,13) in the contact layout ``qw qx qy qz | x y z | wx wy wz (body) | vx vy vz (world)``
at a fixed step ``dt``; the table is the plane z = ``table_height``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from service.mesh import Mesh
from service.model import ObjectModel
from service.residuals.types import ObservedTrajectory, ResidualInputs
from service.session.types import Friction
from service.transforms import make_X, quat_to_mat


def observed_trajectories(states: Sequence[np.ndarray], dt: float) -> tuple[ObservedTrajectory, ...]:
    """(T_k,13) state arrays -> observed trajectories with times ``k·dt`` and the recorded velocities."""
    out = []
    for s in states:
        s = np.asarray(s, float)
        X = make_X(quat_to_mat(s[:, 0:4]), s[:, 4:7])
        out.append(ObservedTrajectory(t=np.arange(len(s)) * float(dt), X_WO=X, v_WO_W=s[:, 10:13], w_WO_O=s[:, 7:10]))
    return tuple(out)


def learned_model(mesh: Mesh, mass: float, mass_declared: bool, com_O: np.ndarray, inertia_O: np.ndarray,
                  friction: Friction) -> ObjectModel:
    """The model the contact stage learned, as the residual loop simulates it (convex geometry)."""
    return ObjectModel(visual=mesh, collision=(mesh,), mass=float(mass), mass_declared=bool(mass_declared),
                       com_O=np.asarray(com_O, float), inertia_O=np.asarray(inertia_O, float), friction=friction,
                       effects={})


def inputs_from_trajectories(states: Sequence[np.ndarray], dt: float, model: ObjectModel, *,
                             table_height: float = 0.0, step_residuals=None) -> ResidualInputs:
    return ResidualInputs(model=model, trajectories=observed_trajectories(states, dt),
                          table_height=float(table_height), robot=None, step_residuals=step_residuals)
