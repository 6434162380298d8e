import numpy as np
import pytest
import trimesh

from service.mesh import Mesh
from service.model import ObjectModel
from service.session.types import Friction
from service.sim import EFFECTS, EffectSpec, RobotPath, SimConfig, rollout, settings_for
from service.transforms import make_X, rotation_angle, so3_exp

CFG = SimConfig.fast()
T = np.arange(0.0, 1.5, 1 / 30)
FAR = np.tile([1.0, 1.0, 0.5], (len(T), 1))


def box_model(ext=(0.1, 0.1, 0.1), mass=0.5, effects=None, shift=(0.0, 0.0, 0.0)):
    """Box whose centre (= centre of mass) is at ``shift`` in O."""
    b = trimesh.creation.box(ext)
    b.apply_translation(shift)
    m = Mesh.from_trimesh(b)
    e = np.asarray(ext)
    inertia = np.diag(mass / 12 * np.array([e[1] ** 2 + e[2] ** 2, e[0] ** 2 + e[2] ** 2, e[0] ** 2 + e[1] ** 2]))
    return ObjectModel(m, (m,), mass, True, np.asarray(shift, float), inertia, Friction(), effects or {})


def ball_model(r=0.04, mass=0.3, effects=None):
    s = trimesh.creation.icosphere(subdivisions=2, radius=r)
    m = Mesh.from_trimesh(s)
    return ObjectModel(m, (m,), mass, True, np.zeros(3), np.eye(3) * 0.4 * mass * r * r, Friction(), effects or {})


def at(z, x=0.0):
    X = np.eye(4)
    X[0, 3], X[2, 3] = x, z
    return X


def test_box_resting_stays_put():
    r = rollout(box_model(), at(0.05), np.zeros(3), np.zeros(3), (T, FAR), 0.0, 0.02, CFG)
    dp = np.linalg.norm(r.X_WO[:, :3, 3] - [0, 0, 0.05], axis=1)
    assert dp.max() < 2e-3
    assert np.degrees(rotation_angle(r.X_WO[:, :3, :3])).max() < 0.5
    assert not r.contact_active.any()
    assert r.table_contact[-1]
    assert r.max_table_penetration < 3e-3


def test_offset_com_frame_is_reported_in_O():
    # O is not at the box centre; the reported X_WO must still be the pose of O
    shift = (0.03, -0.02, 0.01)
    X0 = at(0.05 - 0.01)
    r = rollout(box_model(shift=shift), X0, np.zeros(3), np.zeros(3), (T, FAR), 0.0, 0.02, CFG)
    assert np.abs(r.X_WO[-1, :3, 3] - X0[:3, 3]).max() < 2e-3
    assert np.degrees(rotation_angle(r.X_WO[-1, :3, :3])).max() < 0.5


def test_pushed_box_moves_in_push_direction():
    p = np.stack([-0.2 + 0.12 * T, np.zeros_like(T), np.full_like(T, 0.04)], -1)
    r = rollout(box_model(), at(0.05), np.zeros(3), np.zeros(3), (T, p), 0.0, 0.02, CFG)
    d = r.X_WO[-1, :3, 3] - [0, 0, 0.05]
    assert d[0] > 0.03 and abs(d[1]) < 0.01 and abs(d[2]) < 3e-3
    assert r.contact_active.any() and not r.contact_active[:5].any()
    # the sphere never passes through the box: its centre stays behind the box's back face
    assert np.all(r.p_WE[:, 0] < r.X_WO[:, 0, 3] - 0.05 - 0.02 + 3e-3)
    # kinematic following tracks the commanded path closely away from contact
    assert np.abs(r.p_WE[:5] - p[:5]).max() < 2e-3


def test_friction_pair_slows_sliding():
    v0 = np.array([0.5, 0.0, 0.0])
    slow = rollout(box_model(), at(0.05), v0, np.zeros(3), (T, FAR), 0.0, 0.02, CFG)
    slide = slow.X_WO[-1, 0, 3]
    # Coulomb sliding distance v^2 / (2 mu g) with mu = 0.26
    assert slide == pytest.approx(0.5**2 / (2 * 0.26 * 9.81), rel=0.15)


def test_restitution_makes_a_dropped_object_bounce():
    X0 = at(0.3)
    dead = rollout(ball_model(), X0, np.zeros(3), np.zeros(3), (T, FAR), 0.0, 0.02, CFG)
    live = rollout(ball_model(effects={"restitution": 0.8}), X0, np.zeros(3), np.zeros(3), (T, FAR), 0.0, 0.02, CFG)
    first = np.argmax(dead.X_WO[:, 2, 3] < 0.045)
    assert dead.X_WO[first:, 2, 3].max() < 0.05
    assert live.X_WO[first + 1 :, 2, 3].max() > 0.12


def test_energy_does_not_grow_and_penetration_is_small():
    m = box_model()
    X0 = make_X(so3_exp(np.array([0.3, 0.2, 0.0])), [0, 0, 0.25])
    r = rollout(m, X0, np.zeros(3), np.zeros(3), (T, FAR), 0.0, 0.02, CFG)
    v = r.v_WO_W  # O = CoM here
    ke = 0.5 * m.mass * (v**2).sum(1) + 0.5 * np.einsum("ni,ij,nj->n", r.w_WO_O, m.inertia_O, r.w_WO_O)
    e = ke + m.mass * 9.81 * r.X_WO[:, 2, 3]
    assert e.max() <= e[0] * 1.01
    assert r.max_table_penetration < 5e-3
    assert r.X_WO[-1, 2, 3] == pytest.approx(0.05, abs=3e-3)


def test_deterministic():
    p = np.stack([-0.2 + 0.12 * T, 0.01 * np.ones_like(T), np.full_like(T, 0.03)], -1)
    a = rollout(box_model(), at(0.05), np.zeros(3), np.zeros(3), (T, p), 0.0, 0.02, CFG)
    b = rollout(box_model(), at(0.05), np.zeros(3), np.zeros(3), (T, p), 0.0, 0.02, CFG)
    np.testing.assert_array_equal(a.X_WO, b.X_WO)


def test_clock_offset_delays_the_push():
    p = np.stack([-0.2 + 0.12 * T, np.zeros_like(T), np.full_like(T, 0.04)], -1)
    a = rollout(box_model(), at(0.05), np.zeros(3), np.zeros(3), (T, p), 0.0, 0.02, CFG)
    b = rollout(box_model(effects={"clock_offset": -0.3}), at(0.05), np.zeros(3), np.zeros(3), (T, p), 0.0, 0.02, CFG)
    first = lambda r: np.argmax(r.contact_active)  # noqa: E731
    assert first(b) - first(a) == pytest.approx(9, abs=2)  # 0.3 s at 30 Hz


def test_table_tilt_makes_the_box_slide_downhill():
    # tan(0.35) = 0.36 > mu = 0.26: gravity rotated +0.35 rad about y tips toward -x, the box slides there
    r = rollout(box_model(effects={"table_tilt_y": 0.35}), at(0.05), np.zeros(3), np.zeros(3), (T, FAR), 0.0, 0.02, CFG)
    assert r.X_WO[-1, 0, 3] < -0.05


def test_effect_registry_is_extensible_and_strict():
    with pytest.raises(ValueError, match="unknown effect"):
        settings_for({"wobble": 1.0})
    reg = {**EFFECTS, "heavy": EffectSpec(lambda s, v: settings_for({}, None).__class__(gravity_W=(0, 0, -9.81 * v)), "x")}
    r = rollout(ball_model(effects={"heavy": 2.0}), at(0.5), np.zeros(3), np.zeros(3), (T[:6], FAR[:6]), 0.0, 0.02, CFG,
                effects=reg)
    t = T[5]
    assert r.X_WO[5, 2, 3] == pytest.approx(0.5 - 0.5 * 2 * 9.81 * t * t, abs=0.01)


def test_bad_inputs_are_refused():
    m = box_model()
    with pytest.raises(ValueError, match="robot path"):
        rollout(m, at(0.05), np.zeros(3), np.zeros(3), RobotPath(T, FAR[:, :2]), 0.0, 0.02, CFG)
    bad = ObjectModel(m.visual, m.collision, 0.5, True, np.zeros(3), np.diag([1.0, 0.1, 0.1]), Friction())
    with pytest.raises(ValueError, match="inertia"):
        rollout(bad, at(0.05), np.zeros(3), np.zeros(3), (T, FAR), 0.0, 0.02, CFG)


def test_linear_damping_is_a_viscous_rate():
    # a box sliding on a frictionless table: v(t) = v0 exp(-b t)
    m = box_model(effects={"linear_damping": 2.0, "friction_object_table": 0.0})
    r = rollout(m, at(0.05), np.array([0.4, 0, 0]), np.zeros(3), (T, FAR), 0.0, 0.02, CFG)
    k = 30
    assert r.v_WO_W[k, 0] == pytest.approx(0.4 * np.exp(-2.0 * T[k]), rel=0.05)


def test_impedance_mode_settles_critically_damped_on_a_step_command():
    cfg = SimConfig(dt=1 / 480, robot_mode="impedance")
    cmd = np.tile([0.5, 0.5, 0.3], (len(T), 1))
    cmd[T >= 0.5, 0] += 0.05
    r = rollout(box_model(), at(0.05), np.zeros(3), np.zeros(3), RobotPath(T, cmd, commanded=True), 0.0, 0.02, cfg)
    assert np.abs(r.p_WE[T < 0.5] - [0.5, 0.5, 0.3]).max() < 1e-3  # gravity compensated, holds still
    late = T > 1.0
    assert np.abs(r.p_WE[late, 0] - 0.55).max() < 1e-3
    assert r.p_WE[:, 0].max() < 0.55 + 1e-3  # no overshoot
    # lag: halfway after about 1.68 / omega with omega = sqrt(K / m) = 38.7 rad/s
    k = np.argmax(r.p_WE[:, 0] > 0.525)
    assert 0.02 < T[k] - 0.5 < 0.1


def test_model_without_collision_pieces_uses_the_hull_of_its_visual_mesh():
    from dataclasses import replace

    m = box_model()
    p = np.stack([-0.2 + 0.12 * T, np.zeros_like(T), np.full_like(T, 0.04)], -1)
    a = rollout(m, at(0.05), np.zeros(3), np.zeros(3), (T, p), 0.0, 0.02, CFG)
    b = rollout(replace(m, collision=()), at(0.05), np.zeros(3), np.zeros(3), (T, p), 0.0, 0.02, CFG)
    np.testing.assert_allclose(a.X_WO, b.X_WO, atol=1e-9)
