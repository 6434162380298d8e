"""Synthetic-lab sessions without rendering: the lab's physics, the robot log as robot.csv gives it.

``lab_session(spec)`` lays out the scene with ``service.synth.make_session``'s own ``scene_layout`` (same seed streams),
runs the lab's physics (``service.synth.sim.simulate``: impedance-driven sphere, hidden effects, rolling
resistance, 240 Hz; a hidden ``friction_object_table`` / ``friction_object_robot`` replaces the declared value in
the physics only), and returns what the residual loop would get when tracking were perfect up to a
noise of the given size: the object's poses at the frame times (mesh frame, plus Gaussian noise), the
robot path as the session's ``robot.csv`` holds it (measured sphere centre with the lab's sensor noise,
time stamps shifted by the hidden clock offset), the table height and the declared friction.
The hidden effects are returned separately (the sidecar) and never enter the model or the inputs.

This isolates the residual loop from tracking and contact learning (too slow for a test); the model
given to the loop is built from the catalogue shape and mass with *perturbed* size, inertia and CoM
(``perturbed_model``), standing in for the learned model's errors.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from service.mesh import Mesh
from service.model import ObjectModel
from service.residuals.types import ObservedTrajectory, RobotPath
from service.session.types import Friction
from service.synth import noise as _noise
from service.synth.generate import scene_layout
from service.synth.objects import make_object
from service.synth.sim import EE_RADIUS, simulate
from service.synth.types import SynthSpec
from service.transforms import make_X, so3_exp


@dataclass(frozen=True)
class LabSession:
    trajectory: ObservedTrajectory
    robot: RobotPath
    table_height: float
    declared_friction: Friction
    mass: float
    mesh: Mesh  # true shape, mesh frame M (origin at the centroid)
    inertia_M: np.ndarray  # uniform-density inertia about the centroid (what a model without CoM shift has)
    truth: dict  # hidden effects (sidecar only)


def lab_session(spec: SynthSpec, pose_noise_m: float = 5e-4, pose_noise_rad: float = 0.005) -> LabSession:
    W, H, N, fps = spec.frame_geometry()
    ss = np.random.SeedSequence(int(spec.seed))
    rng_scene, rng_plan, rng_occ, rng_noise, rng_tex = (np.random.default_rng(s) for s in ss.spawn(5))
    obj = make_object(spec.object, spec.scale, spec.mass)
    table_h, start_xy, start_yaw, _, lateral = scene_layout(spec, obj, rng_scene)
    rec = simulate(
        obj, interaction=spec.interaction, table_h=table_h, start_xy=start_xy, start_yaw=start_yaw, lateral=lateral,
        n_frames=N, fps=fps, physics_hz=spec.physics_hz, mu_ot=spec.friction_object_table,
        mu_or=spec.friction_object_robot, effects=spec.effects, rng=rng_plan,
        log_margin=0.2 + abs(spec.effects.clock_offset), rolling_friction=spec.rolling_friction,
    )
    rn = np.random.default_rng(int(spec.seed) + 99991)
    X = rec.X_WM.copy()
    if pose_noise_m > 0:
        X[:, :3, 3] += rn.normal(scale=pose_noise_m, size=(N, 3))
    if pose_noise_rad > 0:
        X[:, :3, :3] = so3_exp(rn.normal(scale=pose_noise_rad, size=(N, 3))) @ X[:, :3, :3]
    robot_p = _noise.noisy_robot(rec.robot_p, rng_noise) if spec.noise else rec.robot_p
    robot = RobotPath(t=rec.robot_t + spec.effects.clock_offset, p_WE=robot_p, cmd_WE=rec.robot_cmd, radius=EE_RADIUS)
    mesh = Mesh.from_trimesh(obj.mesh)
    inertia = np.asarray(obj.mesh.moment_inertia, float) * (obj.mass / obj.mesh.mass)
    sidecar = {"effects": spec.effects.active(), "friction_object_table": (
        spec.effects.friction_object_table if spec.effects.friction_object_table is not None
        else spec.friction_object_table), "friction_object_robot": (
        spec.effects.friction_object_robot if spec.effects.friction_object_robot is not None
        else spec.friction_object_robot)}
    return LabSession(ObservedTrajectory(t=rec.frame_t, X_WO=X), robot, table_h,
                      Friction(spec.friction_object_table, spec.friction_object_robot), obj.mass, mesh, inertia, sidecar)


def perturbed_model(lab: LabSession, *, scale: float = 1.0, mass_factor: float = 1.0, inertia_factor: float = 1.0,
                    com_shift=(0.0, 0.0, 0.0)) -> ObjectModel:
    """A model of the session's object with deliberate errors (size, mass, inertia, CoM), declared friction,
    no collision pieces (the fused visual mesh only, as the pipeline builds it)."""
    V = np.asarray(lab.mesh.vertices, float) * scale
    mesh = dataclasses.replace(lab.mesh, vertices=V) if dataclasses.is_dataclass(lab.mesh) else Mesh(V, lab.mesh.faces)
    m = lab.mass * mass_factor
    I = lab.inertia_M * (m / lab.mass) * scale**2 * inertia_factor
    return ObjectModel(mesh, (), m, True, np.asarray(com_shift, float), I, lab.declared_friction, {})
