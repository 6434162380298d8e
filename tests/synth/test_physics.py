"""Physics ground truth: contacts agree with the geometry, the object rests on the table, effects act."""

import json

import numpy as np
import pytest
import trimesh

from service.synth import HiddenEffects
from service.synth.objects import OBJECT_KINDS, make_object
from service.synth.sim import EE_RADIUS, simulate
from service.transforms import rotation_angle, xyzquat_to_pose


def _sphere_surface_gap(root):
    """Per frame: distance (m) from the sphere's surface to the true mesh (negative = overlap)."""
    mesh = trimesh.load(root / "ground_truth" / "mesh.obj", force="mesh")
    poses = np.loadtxt(root / "ground_truth" / "poses.csv", delimiter=",", skiprows=1)
    r = np.loadtxt(root / "robot.csv", delimiter=",", skiprows=1)
    p_WE = np.stack([np.interp(poses[:, 0], r[:, 0], r[:, k]) for k in (1, 2, 3)], 1)
    gaps = []
    for i in range(len(poses)):
        X = xyzquat_to_pose(poses[i, 1:8])
        p_M = (p_WE[i] - X[:3, 3]) @ X[:3, :3]
        gaps.append(-trimesh.proximity.signed_distance(mesh, p_M[None])[0] - EE_RADIUS)
    return poses[:, 0], np.asarray(gaps)


def test_contact_intervals_match_geometry(clean_tiny):
    _, res = clean_tiny
    t, gap = _sphere_surface_gap(res.session_dir)
    c = np.loadtxt(res.session_dir / "ground_truth" / "contacts.csv", delimiter=",", skiprows=1, ndmin=2)
    assert len(c) >= 1
    inside = np.zeros(len(t), bool)
    clear_outside = np.ones(len(t), bool)
    for a, b in c:
        inside |= (t > a + 0.02) & (t < b - 0.02)
        clear_outside &= (t < a - 0.02) | (t > b + 0.02)
    assert inside.sum() >= 5
    assert np.all(np.abs(gap[inside]) < 1.5e-3)  # touching the exported surface, margin compensated
    assert np.all(gap[clear_outside] > 0.0)


@pytest.mark.parametrize("kind", OBJECT_KINDS)
def test_objects_are_closed_and_rest_on_the_table(kind):
    obj = make_object(kind)
    assert obj.mesh.is_watertight and obj.mesh.volume > 0
    assert 0.05 <= obj.extents.max() <= 0.25 and 0.05 <= obj.mass <= 1.0
    assert np.allclose(obj.mesh.center_mass, 0.0, atol=1e-9)
    parts_vol = sum(p.volume for p in obj.parts)
    assert parts_vol == pytest.approx(obj.mesh.volume, rel=0.12)  # convex pieces cover the solid
    assert all(p.is_convex for p in obj.parts)


def _run(kind, inter, effects=HiddenEffects(), n=60, mu=0.26, seed=0):
    return simulate(
        make_object(kind), interaction=inter, table_h=0.02, start_xy=np.array([0.5, 0.0]), start_yaw=0.4,
        lateral=np.array([1.0, 0.0]), n_frames=n, fps=30.0, physics_hz=240.0, mu_ot=mu, mu_or=0.15, effects=effects,
        rng=np.random.default_rng(seed), rolling_friction=0.0005,
    )


def test_resting_pose_and_push_motion():
    rec = _run("baking_box", "push")
    V = np.asarray(make_object("baking_box").mesh.vertices)
    low = [(V @ X[:3, :3].T + X[:3, 3])[:, 2].min() for X in rec.X_WM]
    assert abs(low[0] - 0.02) < 3e-4  # rests on the table top (z = 0.02), no margin gap
    assert np.all(np.abs(np.asarray(low) - 0.02) < 1.5e-3)
    assert np.linalg.norm(rec.X_WM[-1, :2, 3] - rec.X_WM[0, :2, 3]) > 0.02


def test_pivot_returns_and_topple_falls():
    piv = _run("bottle", "pivot")
    tilt = [rotation_angle(piv.X_WM[0, :3, :3].T @ X[:3, :3]) for X in piv.X_WM]
    assert max(tilt) > np.radians(6) and tilt[-1] < np.radians(2)
    top = _run("oat_carton", "topple", n=90)
    up = top.X_WM[-1, :3, :3] @ top.X_WM[0, :3, :3].T @ np.array([0, 0, 1.0])
    assert abs(up[2]) < 0.2  # lies on a side


def test_effects_change_the_motion():
    base = _run("milk_carton", "topple", n=75)
    for eff in (HiddenEffects(restitution=0.6), HiddenEffects(com_offset=(0.0, 0.0, 0.03)),
                HiddenEffects(angular_damping=3.0), HiddenEffects(friction_object_table=0.6)):
        rec = _run("milk_carton", "topple", eff, n=75)
        dp = np.linalg.norm(rec.X_WM[:, :3, 3] - base.X_WM[:, :3, 3], axis=1).max()
        assert dp > 2e-3, eff


def test_table_tilt_tilts_gravity():
    rec = _run("baking_box", "push", HiddenEffects(table_tilt=(0.05, 0.0)), n=5)
    g = rec.gravity
    assert np.linalg.norm(g) == pytest.approx(9.81)
    assert np.degrees(np.arccos(-g[2] / 9.81)) == pytest.approx(np.degrees(0.05), abs=1e-6)


def test_sidecar_true_values(noisy_tiny):
    spec, res = noisy_tiny
    side = json.loads(res.sidecar_path.read_text())
    t = side["true"]
    obj = make_object(spec.object)
    assert t["mass"] == obj.mass
    I = np.asarray(t["inertia_mesh"])
    assert np.allclose(I, I.T) and np.all(np.linalg.eigvalsh(I) > 0)
    assert t["restitution"] == 0.3 and t["clock_offset"] == 0.0432
    assert side["object"]["kind"] == "bottle"


def test_noise_model_statistics(clean_tiny, tmp_path):
    """Same seed with noise on: same motion; depth differences follow sigma(z); dropouts in range."""
    import cv2

    from service.synth import SynthSpec, make_session
    from service.synth.noise import depth_sigma

    spec, clean = clean_tiny
    noisy = make_session(SynthSpec(**{**spec.__dict__, "noise": True}), tmp_path / "noisy")
    a = (clean.session_dir / "ground_truth" / "poses.csv").read_bytes()
    assert a == (noisy.session_dir / "ground_truth" / "poses.csv").read_bytes()
    res, zs, drops = [], [], []
    for i in (0, 10, 20, 30, 40, 50):
        z0 = cv2.imread(str(clean.session_dir / "depth" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED).astype(float) / 1000
        z1 = cv2.imread(str(noisy.session_dir / "depth" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED).astype(float) / 1000
        flat = (z0 > 0) & (cv2.morphologyEx(z0.astype(np.float32), cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)) < 0.012)
        ok = flat & (z1 > 0)
        res.append((z1 - z0)[ok] / depth_sigma(z0[ok]))
        drops.append(1.0 - ok.sum() / flat.sum())
    r = np.concatenate(res)
    assert len(r) > 20000
    assert abs(np.std(r) - 1.0) < 0.2 and abs(np.mean(r)) < 0.2  # 20 % of the variance is spatially correlated
    assert 0.001 < np.mean(drops) < 0.05
    rc = np.loadtxt(clean.session_dir / "robot.csv", delimiter=",", skiprows=1)
    rn = np.loadtxt(noisy.session_dir / "robot.csv", delimiter=",", skiprows=1)
    assert np.allclose(rc[:, 4:], rn[:, 4:]) and 1e-4 < np.std(rn[:, 1:4] - rc[:, 1:4]) < 4e-4


def test_hidden_robot_friction_acts_and_stays_out_of_the_session(tmp_path):
    # the true object-robot friction replaces the declared one in the physics only: a strike's glancing hit moves
    # the box differently, while session.json still declares the prior and the sidecar has the truth. 120 frames (two
    # strikes): with the step split at the time of impact (the lab's default) the first 60 frames' strike moves the box
    # 0.73 mm apart (1.99 mm with Bullet's push-out kick, which adds normal impulse and so friction); 120 frames: 5.6 mm
    from service.synth import SynthSpec, make_session

    base = _run("baking_box", "strike", n=120, mu=0.15)
    same = _run("baking_box", "strike", HiddenEffects(friction_object_robot=0.15), n=120, mu=0.15)
    assert np.array_equal(same.X_WM, base.X_WM)
    rec = _run("baking_box", "strike", HiddenEffects(friction_object_robot=0.6), n=120, mu=0.15)
    assert np.linalg.norm(rec.X_WM[:, :3, 3] - base.X_WM[:, :3, 3], axis=1).max() > 1e-3
    with pytest.raises(ValueError, match="friction_object_robot"):
        HiddenEffects(friction_object_robot=-0.1)
    spec = SynthSpec(object="baking_box", interaction="strike", seed=1, preset="tiny", n_frames=8, noise=False,
                     effects=HiddenEffects(friction_object_robot=0.6))
    res = make_session(spec, tmp_path / "s")
    assert json.loads((res.session_dir / "session.json").read_text())["friction"]["object_robot"] == 0.15
    side = json.loads(res.sidecar_path.read_text())
    assert side["true"]["friction_object_robot"] == 0.6 and side["sim_effects"]["friction_scale_robot"] == 4.0
