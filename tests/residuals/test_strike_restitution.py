"""The built-in simulator's strike bounce: a sphere driven along a path hits a resting cube on a frictionless table.

A kinematically driven sphere striking through the CoM launches the cube at (1 + e) v. With Bullet's default
contact breaking threshold (0.02 m) the contact point is made many sub-steps before the touch and the bounce is lost in
some contact phases (here 2 of the 6); with ``contact_breaking_m`` = 1 mm it is kept in all; the contact then starts
inside the cube, and Bullet's push-out of that overlap speeds the launch by up to 6 % unless the sub-step is split at
the touch (``touch_split``; docs/residuals.md §6).
"""

from __future__ import annotations

import numpy as np
import pytest

from service.residuals.simulate import BulletSimulator
from service.residuals.types import ResidualConfig, RobotPath, SimRequest
from service.transforms import make_X
from tests.residuals.lab import SIDE, cube_model

V = 0.5  # m/s, sphere speed at the strike
R_SPHERE = 0.0195


def _path(start_gap: float) -> RobotPath:
    """Sphere centre at the cube's CoM height, ``start_gap`` m behind its face, moving along +x at V, then braking
    at 12 m/s² once 2 cm past the face (it stays in contact only while the cube is launched)."""
    rt = np.arange(0.0, 0.8, 1e-3)
    x0 = -SIDE / 2 - R_SPHERE - start_gap
    t_brake = (start_gap + 0.02) / V
    tau = np.clip(rt - t_brake, 0.0, V / 12.0)
    s = np.where(rt < t_brake, V * rt, V * t_brake + V * tau - 6.0 * tau**2)
    return RobotPath(rt, np.stack([x0 + s, np.zeros_like(rt), np.full_like(rt, SIDE / 2)], 1), None, R_SPHERE)


def _launch_speed(sim: BulletSimulator, e: float, start_gap: float) -> float:
    """The cube's x speed (m/s) at the end of the rollout (frictionless table: the launch speed)."""
    t = np.arange(0.0, 0.5, 1 / 30)
    X0 = make_X(np.eye(3), np.array([0.0, 0.0, SIDE / 2]))
    X = sim(SimRequest(cube_model(), X0, np.zeros(3), np.zeros(3), t, 0.0, _path(start_gap),
                       {"restitution": e, "friction_object_table": 0.0}))
    return float((X[-1, 0, 3] - X[-4, 0, 3]) / (t[-1] - t[-4]))


GAPS = 0.03 + np.random.default_rng(0).uniform(0.0, 0.005, 6)  # contact phases within a few sub-steps


def test_strike_launches_with_the_restitution_in_every_contact_phase():
    with BulletSimulator(0.002, contact_breaking_m=0.001) as sim:
        for gap in GAPS:
            v0 = _launch_speed(sim, 0.0, gap)
            v3 = _launch_speed(sim, 0.3, gap)
            assert v0 == pytest.approx(V, rel=0.07), f"start gap {gap:.4f} m"
            assert v3 / v0 == pytest.approx(1.3, abs=0.05), f"start gap {gap:.4f} m"


def test_touch_split_launches_at_the_spheres_speed():
    """With the sub-step split at the sphere's time of impact (``touch_split``, on by default) the contact starts at
    the touch: the e = 0 launch is v in every phase (measured 1.0000 v; with Bullet's push-out of the overlap the
    contact starts with, 1.001-1.059 v) and e = 0.3 gives 1.3 x that (1.2987-1.2996), with Bullet's law (its push-out)
    kept for the contact once made."""
    assert ResidualConfig().touch_split
    with BulletSimulator(0.002, contact_breaking_m=0.001, touch_split=True) as sim:
        v0 = np.array([_launch_speed(sim, 0.0, g) for g in GAPS])
        v3 = np.array([_launch_speed(sim, 0.3, g) for g in GAPS])
    assert np.all(np.abs(v0 / V - 1.0) < 0.002), v0
    assert np.all(np.abs(v3 / v0 - 1.3) < 0.005), v3 / v0


def test_touch_split_keeps_a_path_that_touches_nothing():
    """The split only acts at a touch: a sphere path that passes the cube is replayed bit for bit as without it."""
    rt = np.arange(0.0, 0.6, 1e-3)
    path = RobotPath(rt, np.stack([-0.1 + 0.5 * rt, np.full_like(rt, SIDE / 2 + R_SPHERE + 0.002),
                                   np.full_like(rt, SIDE / 2)], 1), None, R_SPHERE)
    t = np.arange(0.0, 0.5, 1 / 30)
    X0 = make_X(np.eye(3), np.array([0.0, 0.0, SIDE / 2]))
    req = SimRequest(cube_model(), X0, np.zeros(3), np.zeros(3), t, 0.0, path, {"friction_object_table": 0.3})
    with BulletSimulator(0.002, contact_breaking_m=0.001, touch_split=True) as on, \
            BulletSimulator(0.002, contact_breaking_m=0.001) as off:
        assert np.array_equal(on(req), off(req))


def test_contact_breaking_is_put_back_after_each_rollout():
    """Bullet's threshold is a process-wide global: a simulator with its own value leaves other worlds as they were."""
    gap = 0.0312
    with BulletSimulator(0.002) as plain:
        before = _launch_speed(plain, 0.3, gap)
        with BulletSimulator(0.002, contact_breaking_m=0.001) as own:
            _launch_speed(own, 0.3, gap)
        assert _launch_speed(plain, 0.3, gap) == before


def test_contact_breaking_validated():
    with pytest.raises(ValueError, match="contact_breaking_m"):
        ResidualConfig(contact_breaking_m=0.0)
    with pytest.raises(ValueError, match="contact_breaking_m"):
        BulletSimulator(0.002, contact_breaking_m=-1.0)
    with pytest.raises(TypeError):  # removed options (docs/residuals-findings.md, "The launch kick")
        ResidualConfig(contact_erp=0.05)
    with pytest.raises(TypeError):
        ResidualConfig(sphere_velocity_only=True)
    with pytest.raises(ValueError, match="touch_split"):
        ResidualConfig(touch_split="on")


def _drop_peak_rebound(threshold: float) -> float:
    """A cube released 0.1 mm above a table at 0.05 m/s downwards, restitution 0.9: the highest its bottom comes back
    above the table after the first landing, m."""
    t = np.arange(0.0, 0.3, 1 / 240)
    X0 = make_X(np.eye(3), np.array([0.0, 0.0, SIDE / 2 + 1e-4]))
    with BulletSimulator(contact_breaking_m=0.001, restitution_threshold_mps=threshold) as sim:
        X = sim(SimRequest(cube_model(), X0, np.array([0.0, 0.0, -0.05]), np.zeros(3), t, 0.0, None,
                           {"restitution": 0.9}))
    z = X[:, 2, 3] - SIDE / 2
    landed = int(np.argmax(z < 1e-4))
    return float(z[landed:].max())


def test_restitution_threshold_sets_the_slowest_bounce():
    # a slow landing bounces with the loop's 0.05 m/s (about 0.3 mm high) and not with Bullet's 0.2 m/s, which the
    # synthetic lab keeps (ResidualConfig.restitution_threshold_mps)
    assert _drop_peak_rebound(0.05) > 2e-4
    assert _drop_peak_rebound(0.2) < 5e-5
    with pytest.raises(ValueError, match="restitution_threshold_mps"):
        BulletSimulator(restitution_threshold_mps=-1.0)
