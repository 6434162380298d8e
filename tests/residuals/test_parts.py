"""Unit tests of the residual loop's parts: start state, simulator, modes, rule, registry, output, plots."""

import dataclasses

import numpy as np
import pytest

from service.errors import InvalidInput
from service.residuals import run
from service.residuals.effects import REGISTRY, fold_into_model, is_negligible, null_params
from service.residuals.loop import _decide, start_state
from service.residuals.modes import FREE, IMPACT, REST, classify, table_gaps
from service.residuals.plots import plot_heldout_errors, plot_rollout_by_mode, plot_step_residuals
from service.residuals.simulate import BulletSimulator, gravity_vector
from service.residuals.types import (
    EffectCandidate, ObservedTrajectory, ResidualConfig, ResidualInputs, ResidualOutputs, SimRequest,
)
from service.transforms import make_X, rotation_angle, so3_exp
from tests.residuals.lab import SIDE, cube_model


def _free_flight(v0, w0, g, h, n, R0=np.eye(3), p0=np.zeros(3)):
    """Naive semi-implicit Euler reference: v += g h; p += v h; R = R Exp(w h) (torque-free sphere-like)."""
    X = [make_X(R0, p0)]
    v, p, R = np.array(v0, float), np.array(p0, float), np.array(R0, float)
    for _ in range(n - 1):
        v = v + g * h
        p = p + v * h
        R = R @ so3_exp(np.asarray(w0) * h)
        X.append(make_X(R, p))
    return np.array(X)


def test_start_state_recovers_semi_implicit_velocity():
    h = 1 / 148
    g = np.array([0.0, 0.0, -9.81])
    v0, w0 = np.array([0.7, -0.2, 0.4]), np.array([0.0, 0.0, 3.0])  # spin about a fixed axis
    X = _free_flight(v0, w0, g, h, 9, R0=so3_exp(np.array([0.0, 0.0, 0.3])))
    t = np.arange(9) * h
    X0, v, w = start_state(t, X, 4, h)
    # velocity that carried frame 3 -> 4 (backward difference at frame 4) = v0 + 4 g h
    assert np.allclose(v, v0 + 4 * g * h, atol=1e-9)
    assert np.allclose(w, w0, atol=1e-6)
    assert np.allclose(X0, X[4], atol=1e-9)


def test_simulator_free_flight_matches_reference_and_gravity_effects():
    model = cube_model()
    t = np.arange(12) / 148.0
    X0 = make_X(np.eye(3), np.array([0.0, 0.0, 1.0]))
    v0 = np.array([0.5, 0.1, 0.0])
    with BulletSimulator(sim_substep_s=1 / 148.0) as sim:
        for eff in ({}, {"gravity_scale": 0.9}, {"table_tilt_x": 0.1, "table_tilt_y": -0.05}):
            X = sim(SimRequest(model, X0, v0, np.zeros(3), t, 0.0, None, eff))
            ref = _free_flight(v0, np.zeros(3), gravity_vector(eff), 1 / 148.0, len(t), p0=X0[:3, 3])
            assert np.abs(X[:, :3, 3] - ref[:, :3, 3]).max() < 1e-6
    g = gravity_vector({"table_tilt_x": 0.1})
    assert np.isclose(np.linalg.norm(g), 9.81) and g[1] > 0 and abs(g[0]) < 1e-12


def test_simulator_rest_height_and_table_offset():
    model = cube_model()
    t = np.arange(60) / 148.0
    X0 = make_X(np.eye(3), np.array([0.0, 0.0, SIDE / 2 + 0.002]))
    with BulletSimulator() as sim:
        for off in (0.0, -0.001):
            X = sim(SimRequest(model, X0, np.zeros(3), np.zeros(3), t, 0.0, None, {"table_offset": off}))
            assert abs(table_gaps(model, X[-1:], 0.0)[0] - off) < 2e-4


def test_service_sim_adapter_agrees_on_free_flight():
    pytest.importorskip("service.sim")
    from service.residuals.simulate import service_sim_simulator

    model = cube_model()
    t = np.arange(15) / 148.0
    X0 = make_X(so3_exp(np.array([0.2, 0.1, 0.0])), np.array([0.0, 0.0, 0.5]))
    req = SimRequest(model, X0, np.array([0.4, 0.0, 0.3]), np.array([1.0, 2.0, 0.0]), t, 0.0, None, {"gravity_scale": 0.95})
    a = service_sim_simulator()(req)
    with BulletSimulator(sim_substep_s=1 / 480) as sim:
        b = sim(req)
    assert np.abs(a[:, :3, 3] - b[:, :3, 3]).max() < 1e-3
    assert np.degrees(rotation_angle(np.swapaxes(a[:, :3, :3], 1, 2) @ b[:, :3, :3])).max() < 1.0


def test_modes_of_a_drop_to_rest():
    model = cube_model()
    t = np.arange(120) / 148.0
    X0 = make_X(np.eye(3), np.array([0.0, 0.0, 0.15]))
    with BulletSimulator() as sim:
        X = sim(SimRequest(model, X0, np.zeros(3), np.zeros(3), t, 0.0, None, {}))
    mode = classify(model, ObservedTrajectory(t, X), 0.0, None, ResidualConfig())
    assert mode[0] == FREE and mode[-1] == REST
    first_contact = np.flatnonzero(mode != FREE)[0]
    assert mode[first_contact] == IMPACT or mode[first_contact - 1] == IMPACT
    # a free fall from 0.15 m (lowest face 0.0976 m above the table) lasts sqrt(2·0.0976/9.81) s
    assert abs(t[first_contact] - np.sqrt(2 * (0.15 - SIDE / 2) / 9.81)) < 3 / 148.0


def test_acceptance_rule():
    rng = np.random.default_rng(0)
    cfg = ResidualConfig()
    before = rng.uniform(2e-3, 4e-3, 40)
    units = np.arange(40) // 2
    ok, why, _ = _decide(before, before * 0.7 + rng.normal(0, 1e-5, 40), units, cfg, rng)
    assert ok, why
    # a large mean fall carried by half of the blocks while the other half get worse is not consistent
    d = np.where(np.arange(40) % 2 == 0, 2e-3, -1e-3)
    ok, why, _ = _decide(before, before - d, units, cfg, rng)
    assert not ok and "not consistent" in why
    # random changes without a mean fall are noise
    ok, why, _ = _decide(before, before + rng.normal(0, 1e-3, 40), np.arange(40), cfg, rng)
    assert not ok and why.startswith("rejected")
    # consistent but tiny improvements fall under the minimum relative fall
    ok, why, _ = _decide(before, before * 0.99, units, cfg, rng)
    assert not ok and "fall below" in why


def test_registry_is_consistent():
    model = cube_model()
    keys = [k for e in REGISTRY.values() for k in e.params]
    assert len(keys) == len(set(keys))
    for e in REGISTRY.values():
        assert len(e.lower) == len(e.upper) == len(e.null) == len(e.params) == len(e.resolution)
        assert all(lo < hi for lo, hi in zip(e.lower, e.upper))
        guess = e.guess({}, model)  # no statistics at all: still a valid start inside the bounds
        assert e.clip(guess) == tuple(float(x) for x in guess)
        assert is_negligible(e, null_params(e, model), model)


def test_fold_into_model_keeps_the_urdf_and_simulator_consistent():
    model = cube_model(friction=(0.2, 0.3))
    out, rec = fold_into_model(model, {"friction_object_table": 0.4, "friction_scale_robot": 2.0,
                                       "restitution": 0.3, "gravity_scale": 0.98}, carried={"restitution"})
    assert out.friction.object_table == 0.4 and np.isclose(out.friction.object_robot, 0.6)
    assert out.effects == {"restitution": 0.3}
    assert rec == {"gravity_scale": 0.98}


def test_bad_input_names_the_field():
    model = cube_model()
    t = np.arange(10) / 30.0
    bad = ObservedTrajectory(t, np.tile(np.eye(4), (9, 1, 1)))
    with pytest.raises(InvalidInput, match=r"trajectories\[0\]"):
        run(ResidualInputs(model, (bad,), 0.0), ResidualConfig.fast())
    good = ObservedTrajectory(t, np.tile(np.eye(4), (10, 1, 1)))
    with pytest.raises(InvalidInput, match="candidates"):
        run(ResidualInputs(model, (good, good), 0.0), dataclasses.replace(ResidualConfig.fast(), candidates=("nope",)))


def test_plots_and_report(tmp_path):
    rb = {m: {"frames": 10, "pos_err_m": 0.002, "rot_err_deg": 1.0} for m in ("free_flight", "rest")}
    ra = {m: {"frames": 10, "pos_err_m": 0.001, "rot_err_deg": 0.9} for m in ("free_flight", "rest")}
    cand = EffectCandidate("gravity_scale", {"gravity_scale": 0.98}, 2e-3, 1e-3, True, "accepted: test")
    out = ResidualOutputs(
        (cand,), ("gravity_scale",), {"gravity_scale": 0.98}, {"pos_err_m": 0.002}, {"pos_err_m": 0.001},
        by_mode={"rollout_before": rb, "rollout_after": ra, "residual": {}},
        series={"heldout_error_before": np.array([2e-3, 3e-3]), "heldout_error_after": np.array([1e-3, 2e-3])},
    )
    for f in (plot_rollout_by_mode, plot_heldout_errors, plot_step_residuals):
        p = f(out, tmp_path / "p" / f"{f.__name__}.png")
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rep = out.report()
    assert rep["accepted"] == ["gravity_scale"]
    assert rep["candidates"][0]["params"] == {"gravity_scale": 0.98}
    assert set(rep) >= {"candidates", "accepted", "error_before", "error_after"}


def test_simulator_robot_push_and_clock_offset():
    from service.residuals.types import RobotPath

    model = cube_model(friction=(0.3, 0.3))
    t = np.arange(40) / 30.0
    path_t = np.linspace(-1.0, 3.0, 400)
    # sphere (r 0.0195) sweeps +x through the cube's left face from x = -0.12 at 0.15 m/s, 3 cm high
    path = RobotPath(path_t, np.stack([-0.12 + 0.15 * np.clip(path_t, 0, None), 0 * path_t, 0.03 + 0 * path_t], 1), None, 0.0195)
    X0 = make_X(np.eye(3), np.array([0.0, 0.0, SIDE / 2]))
    with BulletSimulator() as sim:
        X = sim(SimRequest(model, X0, np.zeros(3), np.zeros(3), t, 0.0, path, {}))
        Xd = sim(SimRequest(model, X0, np.zeros(3), np.zeros(3), t, 0.0, path, {"clock_offset": 0.2}))
    # contact at (0.12 - 0.0524 - 0.0195) / 0.15 = 0.32 s; the cube then moves with the sphere
    x_end = -0.12 + 0.15 * t[-1] + 0.0195 + SIDE / 2
    assert abs(X[-1, 0, 3] - x_end) < 0.01
    assert abs(X[-1, 1, 3]) < 0.01 and abs(X[-1, 2, 3] - SIDE / 2) < 0.002
    # a robot clock 0.2 s ahead pushes 0.2 s earlier: 3 cm further at the end
    assert abs((Xd[-1, 0, 3] - X[-1, 0, 3]) - 0.15 * 0.2) < 0.005


def test_outputs_survive_the_artifact_store(tmp_path):
    from service.io import load_value, save_value

    cand = EffectCandidate("restitution", {"restitution": 0.3}, 2e-3, 1e-3, True, "accepted: test",
                           blocks={"train": 3, "heldout": 4})
    model = dataclasses.replace(cube_model(), effects={"restitution": 0.3})
    out = ResidualOutputs((cand,), ("restitution",), {"restitution": 0.3}, {"pos_err_m": 0.002}, {"pos_err_m": 0.001},
                          by_mode={"residual": {"rest": {"frames": 3, "gap_mean": -0.001}}}, model=model,
                          series={"heldout_error_before": np.array([1.0, 2.0])}, recording_effects={"gravity_scale": 0.98})
    save_value(out, tmp_path / "v")
    back = load_value(ResidualOutputs, tmp_path / "v")
    assert back.accepted == ("restitution",) and back.candidates[0].params == {"restitution": 0.3}
    assert back.model.effects == {"restitution": 0.3} and np.allclose(back.model.inertia_O, model.inertia_O)
    assert back.recording_effects == {"gravity_scale": 0.98}
    assert np.array_equal(back.series["heldout_error_before"], [1.0, 2.0])


def test_simulator_damping_is_viscous():
    """v(t) = v0 e^{−bt} and ω(t) = ω0 e^{−bt} (sphere-like cube): distance (1 − e^{−b})/b after 1 s."""
    t = np.arange(149) / 148.0
    with BulletSimulator() as sim:
        X = sim(SimRequest(cube_model(), make_X(np.eye(3), np.array([0, 0, 5.0])), np.array([1.0, 0, 0]),
                           np.array([0, 0, 5.0]), t, 0.0, None,
                           {"gravity_scale": 0.0, "linear_damping": 1.5, "angular_damping": 0.8}))
    assert abs(X[-1, 0, 3] - (1 - np.exp(-1.5)) / 1.5) < 3e-3
    yaw = np.unwrap(np.arctan2(X[:, 1, 0], X[:, 0, 0]))
    assert abs(yaw[-1] - 5.0 * (1 - np.exp(-0.8)) / 0.8) < 0.02


def _slide_poses(t, launches_at, v0=0.4, decel=1.5, heading=(1.0, 0.0)):
    """Poses (N,4,4) of a box at rest, launched at v0 at the given times and sliding to rest at ``decel``."""
    p = np.zeros((len(t), 3))
    pos = np.zeros(3)
    d = np.array([heading[0], heading[1], 0.0])
    for k in range(1, len(t)):
        dt = t[k] - t[k - 1]
        speed = 0.0
        for ta in launches_at:
            if t[k] >= ta:
                speed = max(v0 - decel * (t[k] - ta), 0.0)
        pos = pos + d * speed * dt
        p[k] = pos
    return np.stack([make_X(np.eye(3), q) for q in p])


def test_launches_found_for_strikes_not_for_quasi_static_pushes():
    from service.residuals.loop import launches

    cfg = ResidualConfig()
    t = np.arange(180) / 30.0
    X = _slide_poses(t, [1.0, 3.0])
    ev = launches(t, X, np.ones(len(t), bool), cfg)
    # the object moves from frames 30 and 90; the onset is the first frame whose next 3 speeds pass 0.15 m/s
    assert len(ev) == 2 and 28 <= ev[0][0] <= 30 and 88 <= ev[1][0] <= 90
    for a, b in ev:  # the block covers the slide (0.4 / 1.5 = 0.27 s, 8 frames) and ends at rest
        assert 8 <= b - a <= 14 and np.linalg.norm(X[b - 1, :3, 3] - X[min(b + 5, len(t) - 1), :3, 3]) < 1e-9
    # a quasi-static push: smooth-step to 0.15 m/s over 0.5 s (0.45 m/s^2 peak) never triggers it
    s = np.clip((t - 1.0) / 1.0, 0, 1)
    P = np.stack([0.1 * (3 * s**2 - 2 * s**3), np.zeros_like(t), np.zeros_like(t)], 1)
    Xp = np.stack([make_X(np.eye(3), q) for q in P])
    assert launches(t, Xp, np.ones(len(t), bool), cfg) == []


def test_smooth_robot_removes_sensor_noise_keeps_the_path():
    from service.residuals.loop import smooth_robot
    from service.residuals.types import RobotPath

    t = np.arange(480) / 240.0
    true = np.stack([0.3 * t, 0.05 * np.sin(3 * t), np.zeros_like(t)], 1)
    noisy = true + np.random.default_rng(0).normal(scale=2e-4, size=true.shape)
    sm = smooth_robot(RobotPath(t, noisy, None, 0.0195), ResidualConfig())
    v_noisy = np.linalg.norm(np.diff(noisy, axis=0), axis=1) * 240
    v_sm = np.linalg.norm(np.diff(sm.p_WE, axis=0), axis=1) * 240
    v_true = np.linalg.norm(np.diff(true, axis=0), axis=1) * 240
    assert np.abs(v_noisy - v_true).mean() > 0.04  # 0.2 mm at 240 Hz: ~0.07 m/s of velocity noise
    assert np.abs(v_sm - v_true).mean() < 0.25 * np.abs(v_noisy - v_true).mean()
    assert np.abs(sm.p_WE - true).max() < 1e-3
    # off: unchanged
    assert smooth_robot(RobotPath(t, noisy, None, 0.0195), ResidualConfig(robot_smooth_s=0.0)).p_WE is noisy


def test_tilt_needs_better_blocks_downhill_and_uphill():
    from service.residuals.loop import Segment, direction_check

    eff = REGISTRY["table_tilt"]
    theta = (0.0, 0.05)  # tilt about world y: downhill u = horizontal part of the tilted gravity
    u = gravity_vector({"table_tilt_x": 0.0, "table_tilt_y": 0.05})[:2]
    u = u / np.linalg.norm(u)

    def seg(sign):
        t = np.arange(10) / 30.0
        X = np.stack([make_X(np.eye(3), np.r_[sign * u * 0.02 * k / 9, 0.0]) for k in range(10)])
        return Segment(0, 0, 10, t, X, np.ones(10, bool), np.zeros(10, int), X[0], np.zeros(3), np.zeros(3), None)

    segs = [seg(1), seg(1), seg(-1), seg(-1)]
    ok, why = direction_check(eff, theta, segs, np.array([3e-3] * 4), np.array([2e-3] * 4))
    assert ok, why
    # helps the blocks going downhill, hurts those going uphill: a model error, not a tilt
    ok, why = direction_check(eff, theta, segs, np.array([3e-3] * 4), np.array([2e-3, 2e-3, 4e-3, 4e-3]))
    assert not ok and "uphill 2" in why
    ok, _ = direction_check(eff, theta, segs[:3], np.array([3e-3] * 3), np.array([2e-3] * 3))  # one uphill block
    assert not ok
