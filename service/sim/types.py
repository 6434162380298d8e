"""Values of the rollout simulator (frames and units as in docs/conventions.md)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


# (stiffness N/m, damping N s/m) of Bullet's per-body contact law (``changeDynamics(contactStiffness, contactDamping)``)
# that solves a body's contacts at the velocity level only: at the step h the pair's erp is h k / (h k + d) = 0 (an
# overlap is left until the bodies part, not pushed out through the velocity) and its cfm 1 / (h (h k + d)) = 1 / (h d)
# (2.4e-4 /kg at 240 Hz, 5e-4 /kg at 2 ms) is negligible against the inverse effective mass of a sphere-object pair
# (> 1 /kg for objects under 1 kg). Bullet's split impulse (a position-only push-out) would be the usual remedy, but
# its multibody solver, which pybullet's bodies use, does not implement it (measured: no effect, bit for bit). Used,
# off by default, by the synthetic lab's strike sphere (``service.synth.sim.STRIKE_VELOCITY_ONLY``; the residual loop's
# sphere had the same option, removed after it was measured: docs/residuals-findings.md, "The launch kick").
VELOCITY_ONLY_CONTACT: tuple[float, float] = (0.0, 1.0e6)


@dataclass(frozen=True)
class SimConfig:
    """Settings of one open-loop rollout.

    ``robot_mode``:
    - ``"kinematic"``: the sphere follows the given path with a very stiff, critically damped,
      gravity-compensated PD (natural frequency ``follow_omega``), i.e. it replays the recorded path;
    - ``"impedance"``: the path is a command; a Cartesian spring–damper of stiffness
      ``impedance_stiffness`` (damping ``2ζ√(K m_E)`` on the absolute velocity) pulls the sphere toward the command,
      after an optional first-order low-pass of the command (``cmd_lowpass_tau``), so contact forces
      deflect the sphere as they deflect a real impedance-controlled arm.
    """

    dt: float = 1.0 / 1000.0  # s, simulator step
    solver_iterations: int = 50
    robot_mode: str = "kinematic"  # "kinematic" | "impedance"
    ee_mass: float = 1.0  # kg, effective mass of the end effector
    follow_omega: float = 150.0  # rad/s, kinematic following bandwidth
    impedance_stiffness: float = 1500.0  # N/m
    impedance_damping_ratio: float = 1.0
    cmd_lowpass_tau: float = 0.0  # s, 0 = no filter
    max_ee_force: float = 400.0  # N, clamp of the actuator force
    contact_force_threshold: float = 1e-3  # N, robot-object contact counts as active above this
    resolve_initial_penetration: bool = True  # lift the object out of the table at t0 if needed
    collision_margin: float = 0.0005  # m, Bullet convex margin of the object
    table_friction_base: float = 1.0  # friction given to the object itself; pairs are products in Bullet

    @classmethod
    def fast(cls) -> "SimConfig":
        return cls(dt=1.0 / 480.0, solver_iterations=30)


@dataclass(frozen=True)
class RobotPath:
    """End-effector sphere-centre path in W: ``t`` (M,) s increasing, ``p_WE`` (M,3) m."""

    t: np.ndarray
    p_WE: np.ndarray
    commanded: bool = False  # True when p_WE are commands (cmd_*) rather than measured positions


@dataclass(frozen=True)
class RolloutResult:
    """A simulated trajectory sampled at the requested times (N samples)."""

    t: np.ndarray  # (N,) s
    X_WO: np.ndarray  # (N,4,4) simulated object pose
    v_WO_W: np.ndarray  # (N,3) velocity of O's origin in W
    w_WO_O: np.ndarray  # (N,3) angular velocity in O axes
    p_WE: np.ndarray  # (N,3) simulated sphere centre
    contact_active: np.ndarray  # (N,) bool: robot-object normal force above threshold since the previous sample
    robot_force: np.ndarray  # (N,) N, largest robot-object normal force since the previous sample
    table_contact: np.ndarray  # (N,) bool: object touching the table at the sample
    max_table_penetration: float  # m, deepest object-table penetration over the whole rollout
    lifted_at_start: float  # m, how far the initial pose was lifted out of the table
