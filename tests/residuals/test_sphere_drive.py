"""How the rollouts drag the robot sphere along its measured path (``ResidualConfig.sphere_drive``,
docs/residuals.md §6): the constraint's targets, and the launch speed a strike hands the object."""

import numpy as np
import pytest

from service.residuals.simulate import CONSTRAINT_ERP, BulletSimulator, make_simulator, sphere_targets
from service.residuals.types import ResidualConfig, RobotPath, SimRequest
from service.transforms import make_X
from tests.residuals.lab import SIDE, cube_model


def _follow(targets: np.ndarray, x0: np.ndarray, erp: float = CONSTRAINT_ERP) -> np.ndarray:
    """The constraint's update of a free sphere, x_j = x_{j-1} + erp (u_j - x_{j-1})."""
    x = [np.asarray(x0, float)]
    for u in targets[1:]:
        x.append(x[-1] + erp * (u - x[-1]))
    return np.array(x)


def _strike_path(h: float, v_hit: float = 0.5, run_up: float = 0.05, brake: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """(t, x) of the lab's strike along +x: constant acceleration to v_hit over ``run_up``, then braking to rest
    within ``brake`` (12.5 m/s² at 0.5 m/s), sampled every h, starting at rest at x = 0."""
    a1, a2 = v_hit**2 / (2 * run_up), v_hit**2 / (2 * brake)
    t1, t2 = v_hit / a1, v_hit / a2
    t = np.arange(-0.2, t1 + t2 + 0.3, h)
    x = np.where(t < 0, 0.0, np.where(t < t1, 0.5 * a1 * t**2, np.where(
        t < t1 + t2, run_up + v_hit * (t - t1) - 0.5 * a2 * (t - t1) ** 2, run_up + brake)))
    return t, x


def test_inverse_targets_put_the_free_sphere_on_any_path():
    h = 0.002
    t, x = _strike_path(h)
    p = np.stack([x, 0 * x, 0 * x], 1)
    on_path = _follow(sphere_targets(p), p[0])
    assert np.abs(on_path - p).max() < 1e-12
    # reading the path (1 - erp)/erp sub-steps ahead is exact at a constant velocity only: at the brake the sphere
    # rounds its speed peak (the strike's launch speed)
    lead = (1 - CONSTRAINT_ERP) / CONSTRAINT_ERP
    ahead = np.stack([np.interp(t + lead * h, t, x), 0 * x, 0 * x], 1)
    lagged = _follow(ahead, ahead[0])
    v_path, v_lag = np.diff(x) / h, np.diff(lagged[:, 0]) / h
    assert v_lag.max() < v_path.max() - 0.01  # 0.4795 against 0.4975 m/s
    # the lead is exact while the speed is steady (the sphere's position then matches its path)
    steady = np.stack([0.3 * t, 0 * t, 0 * t], 1)
    ahead = np.stack([0.3 * (t + lead * h), 0 * t, 0 * t], 1)
    assert np.abs(_follow(ahead, steady[0])[200:] - steady[200:]).max() < 1e-9


def test_inverse_drive_hands_a_struck_cube_the_sphere_speed():
    """A sphere striking a resting cube at 0.5 m/s at the height of its CoM and braking at 12.5 m/s² (the lab's
    strike): with the inverse drive the cube leaves at >= 93 % of the strike speed, with the lead < 91 % (the sphere
    rounded its speed peak); the cube slides farther accordingly."""
    t_path, x = _strike_path(1 / 240.0)
    x = x - 0.05 - SIDE / 2 - 0.0195  # the sphere (r 19.5 mm) reaches the cube's face after its run-up
    path = RobotPath(t_path, np.stack([x, 0 * x, SIDE / 2 + 0 * x], 1), None, 0.0195)
    model = cube_model(friction=(0.15, 0.15))
    t = np.arange(0.0, 0.6, 1 / 240.0)
    X0 = make_X(np.eye(3), np.array([0.0, 0.0, SIDE / 2]))
    peak, travel = {}, {}
    for drive in ("lead", "inverse"):
        with BulletSimulator(sphere_drive=drive) as sim:
            X = sim(SimRequest(model, X0, np.zeros(3), np.zeros(3), t, 0.0, path, {}))
        peak[drive] = float((np.diff(X[:, 0, 3]) * 240.0).max())
        travel[drive] = float(X[-1, 0, 3])
    assert peak["inverse"] >= 0.93 * 0.5 and peak["lead"] < 0.91 * 0.5, peak
    assert travel["inverse"] > 1.05 * travel["lead"], travel


def test_sphere_drive_setting():
    # the loop's default: the inverse drive on the biweight path over 0.08 s, with the touch split (docs/residuals-findings.md,
    # "The split and the inverse drive together"); the simulator built alone keeps the lead
    cfg = ResidualConfig()
    assert (cfg.sphere_drive, cfg.robot_smooth_weights, cfg.robot_smooth_s) == ("inverse", "biweight", 0.08)
    assert make_simulator().sphere_drive == "lead"
    with pytest.raises(ValueError, match="sphere_drive"):
        ResidualConfig(sphere_drive="exact")
    with pytest.raises(ValueError, match="sphere_drive"):
        BulletSimulator(sphere_drive="exact")


def test_biweight_smoothing_is_exact_for_a_constant_acceleration():
    """The biweight local quadratic fit keeps any quadratic path (a constant acceleration, a brake) exactly, edges
    included; "box" is the Savitzky-Golay fit as before."""
    from scipy.signal import savgol_filter

    from service.residuals.loop import local_quadratic, smooth_robot

    t = np.arange(120) / 240.0
    p = np.stack([0.1 + 0.4 * t - 6.25 * t**2, 0.02 - 0.1 * t + 0.8 * t**2, 0.05 + 0 * t], 1)
    assert np.abs(local_quadratic(p, 9) - p).max() < 1e-12
    noisy = p + np.random.default_rng(1).normal(scale=2e-4, size=p.shape)
    path = RobotPath(t, noisy, None, 0.0195)
    box = ResidualConfig(robot_smooth_s=0.04, robot_smooth_weights="box")
    assert np.array_equal(smooth_robot(path, box).p_WE, savgol_filter(noisy, 11, 2, axis=0, mode="interp"))
    bi = smooth_robot(path, ResidualConfig(robot_smooth_s=0.08, robot_smooth_weights="biweight")).p_WE
    assert np.array_equal(bi, local_quadratic(noisy, 9))
    with pytest.raises(ValueError, match="robot_smooth_weights"):
        ResidualConfig(robot_smooth_weights="gauss")


def test_biweight_smoothing_does_not_kick_the_launch():
    """The lab's strike path (12.5 m/s² brake at 0.5 m/s) with the lab's robot sensor noise (0.2 mm, 240 Hz): the
    fastest sample-to-sample speed of the smoothed path (what the inverse drive hands a struck object) is, averaged over
    noise draws, 1.1 % above its noise-free value with the 0.04 s Savitzky-Golay window (the noise's largest kick),
    0.1 % with the 0.08 s biweight fit, whose sample-to-sample speeds also scatter less."""
    from service.residuals.loop import smooth_robot

    t, x = _strike_path(1 / 240.0)
    p = np.stack([x, 0 * x, 0 * x], 1)
    rng = np.random.default_rng(0)
    draws = [rng.normal(scale=2e-4, size=p.shape) for _ in range(200)]
    kick, scatter = {}, {}
    for name, cfg in (("box", ResidualConfig(robot_smooth_s=0.04, robot_smooth_weights="box")),
                      ("biweight", ResidualConfig(robot_smooth_s=0.08, robot_smooth_weights="biweight"))):
        clean = np.diff(smooth_robot(RobotPath(t, p, None, 0.0195), cfg).p_WE[:, 0]).max() * 240.0
        peaks = [np.diff(smooth_robot(RobotPath(t, p + n, None, 0.0195), cfg).p_WE[:, 0]).max() * 240.0 for n in draws]
        kick[name] = np.mean(peaks) / clean - 1.0
        scatter[name] = np.std(peaks)
    assert kick["box"] > 0.006 and abs(kick["biweight"]) < 0.004, kick
    assert scatter["biweight"] < 0.7 * scatter["box"], scatter
