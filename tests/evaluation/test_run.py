from pathlib import Path

import numpy as np
import pytest
import trimesh

from service.errors import InvalidSession
from service.evaluation import EvaluationConfig, EvaluationInputs, load_ground_truth, run
from service.evaluation.ground_truth import GroundTruth
from service.mesh import Mesh
from service.model import ObjectModel
from service.session.types import Friction, Session
from service.sim import SimConfig, rollout
from service.transforms import make_X, pose_to_xyzquat, so3_exp

FPS = 30.0
T = np.arange(0, 1.6, 1 / FPS)
EXT = (0.08, 0.06, 0.10)


def box_model(ext=EXT, mass=0.3):
    m = Mesh.from_trimesh(trimesh.creation.box(ext))
    e = np.asarray(ext)
    inertia = np.diag(mass / 12 * np.array([e[1] ** 2 + e[2] ** 2, e[0] ** 2 + e[2] ** 2, e[0] ** 2 + e[1] ** 2]))
    return ObjectModel(m, (m,), mass, True, np.zeros(3), inertia, Friction(), {})


def session(root: Path, p_WE: np.ndarray, has_gt: bool) -> Session:
    return Session(
        name="unit", root=root, sha256="0" * 64, frame_times=T, K=np.eye(3), X_WC=np.eye(4), depth_scale=0.001,
        width=4, height=3, rgb_files=(), depth_files=(), mask_files=(), robot_t=T, robot_p_WE=p_WE,
        robot_cmd_WE=None, p_WE=p_WE, cmd_WE=None, ee_radius=0.0195, table_height=0.0,
        table_height_detected=False, friction=Friction(), mass=0.3, has_ground_truth=has_gt,
    )


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A box pushed along +x; its rollout with the true model is the 'tracked' trajectory."""
    root = tmp_path_factory.mktemp("sess")
    p = np.stack([-0.15 + 0.15 * T, np.zeros_like(T), np.full_like(T, 0.03)], -1)
    true = box_model()
    X0 = np.eye(4)
    X0[2, 3] = EXT[2] / 2
    r = rollout(true, X0, np.zeros(3), np.zeros(3), (T, p), 0.0, 0.0195, SimConfig.fast())
    # ground truth in its own frame G: offset from O by a fixed transform
    X_OG = make_X(so3_exp(np.array([0.0, 0.0, 0.4])), [0.01, -0.02, 0.005])
    X_GO = np.linalg.inv(X_OG)
    gt = root / "ground_truth"
    gt.mkdir()
    Mesh(np.asarray(true.visual.vertices) @ X_GO[:3, :3].T + X_GO[:3, 3], true.visual.faces).save_obj(gt / "mesh.obj")
    X_WG = r.X_WO @ X_OG
    rows = np.c_[T, pose_to_xyzquat(X_WG)]
    np.savetxt(gt / "poses.csv", rows, delimiter=",", header="t,x,y,z,qw,qx,qy,qz", comments="")
    on = np.flatnonzero(r.contact_active)
    (gt / "contacts.csv").write_text(f"t_start,t_end\n{T[on[0]]},{T[on[-1]]}\n")
    # methods: fused = truth, vision_only = the visible half, physics_only = 20 % larger box
    half = trimesh.creation.box((EXT[0] / 2, EXT[1], EXT[2]))
    half.apply_translation([-EXT[0] / 4, 0, 0])
    big = box_model(tuple(1.2 * np.asarray(EXT)))
    meshes = {"vision_only": Mesh.from_trimesh(half), "physics_only": big.visual, "fused": true.visual}
    thin = box_model((0.04, 0.06, 0.10))
    models = {"vision_only": thin, "physics_only": big, "fused": true}
    inp = EvaluationInputs(session(root, p, True), T, r.X_WO, np.ones(len(T), bool), meshes, models)
    return inp, r


@pytest.fixture(scope="module")
def out(scene):
    inp, _ = scene
    calls = []
    o = run(inp, EvaluationConfig.fast(), progress=lambda f, m: calls.append(f))
    assert calls[0] == 0.0 and calls[-1] == 1.0 and all(0 <= c <= 1 for c in calls)
    return o


def test_tracking_against_ground_truth_is_exact_for_exact_poses(out):
    tr = out.tracking
    assert tr["rot_err_deg_median"] < 1e-6 and tr["trans_err_m_max"] < 1e-6
    assert tr["frames_compared"] == len(T)


def test_geometry_ranks_the_methods(out):
    g = out.geometry
    assert g["fused"]["chamfer_m"] < 0.004 and g["fused"]["iou"] > 0.9
    assert g["physics_only"]["iou"] == pytest.approx(1 / 1.2**3, abs=0.08)
    assert g["vision_only"]["chamfer_m"] > 2 * g["fused"]["chamfer_m"]
    assert g["fused"]["alignment"]["shift_m"] < 0.003


def test_dynamics_of_the_true_model_reproduce_the_trajectory(out, scene):
    d = out.dynamics
    for m in ("fused", "ground_truth_geometry"):
        assert d[m]["pos_err_m"] < 0.003, m
        assert d[m]["rot_err_deg"] < 1.0, m
        assert d[m]["time_before_divergence_s"] == pytest.approx(T[-1] + 1e-3)
        assert d[m]["contact_iou"] > 0.95
        assert d[m]["contact_iou_jaccard"] > 0.9
    # a thinner box is pushed later and less far
    assert d["vision_only"]["pos_err_m"] > 3 * d["fused"]["pos_err_m"]
    assert d["vision_only"]["contact_iou"] < d["fused"]["contact_iou"]
    assert out.series["dynamics/fused/p_WO"].shape == (len(T), 3)


def test_without_ground_truth_metrics_are_null_with_reasons(scene):
    inp, _ = scene
    s = inp.session.__class__(**{**inp.session.__dict__, "has_ground_truth": False})
    o = run(EvaluationInputs(s, inp.t, inp.X_WO, inp.tracked, inp.meshes, inp.models),
            EvaluationConfig.fast())
    assert o.tracking["rot_err_deg_median"] is None and "reason" in o.tracking
    assert o.geometry["fused"]["chamfer_m"] is None and o.geometry["fused"]["reason"]
    assert o.dynamics["fused"]["pos_err_m"] < 0.003
    assert o.dynamics["fused"]["contact_iou"] is None and o.dynamics["fused"]["contact_iou_reason"]
    assert o.dynamics["ground_truth_geometry"]["pos_err_m"] is None


def test_ground_truth_reading(scene, tmp_path):
    inp, _ = scene
    gt = load_ground_truth(inp.session.root)
    assert isinstance(gt, GroundTruth) and gt.X_WG.shape == (len(T), 4, 4) and gt.contacts.shape == (1, 2)
    assert gt.contact_at(np.array([gt.contacts[0, 0], gt.contacts[0, 1] + 0.01])).tolist() == [True, False]
    assert load_ground_truth(tmp_path) is None
    (tmp_path / "ground_truth").mkdir()
    (tmp_path / "ground_truth" / "poses.csv").write_text("t,x,y,z,qw,qx,qy\n0,0,0,0,1,0,0\n")
    with pytest.raises(InvalidSession, match="ground_truth/poses.csv.*qz"):
        load_ground_truth(tmp_path)
    (tmp_path / "ground_truth" / "poses.csv").write_text("t,x,y,z,qw,qx,qy,qz\n0,0,0,0,2,0,0,0\n")
    with pytest.raises(InvalidSession, match="unit norm"):
        load_ground_truth(tmp_path)
    (tmp_path / "ground_truth" / "poses.csv").unlink()
    (tmp_path / "ground_truth" / "contacts.csv").write_text("t_start,t_end\n1.0,0.5\n")
    with pytest.raises(InvalidSession, match="contacts.csv"):
        load_ground_truth(tmp_path)


def test_initial_velocity_body_rates_and_rest():
    from service.evaluation.run import initial_velocity

    t = np.array([0.0, 0.1])
    R0 = so3_exp(np.array([0.0, 0.0, 1.0]))
    X = np.stack([make_X(R0, [0, 0, 0]), make_X(R0 @ so3_exp(np.array([0.05, 0.0, 0.0])), [0.01, 0.0, 0.0])])
    v, w = initial_velocity(t, X, 0, 1, 0.002, 1.0)
    np.testing.assert_allclose(v, [0.1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(w, [0.5, 0, 0], atol=1e-9)  # body axes
    X[1, :3, 3] = [0.0005, 0, 0]
    X[1, :3, :3] = R0 @ so3_exp(np.array([0.005, 0.0, 0.0]))
    v, w = initial_velocity(t, X, 0, 1, 0.002, 1.0)
    assert not v.any() and not w.any()


def test_collision_pieces_of_a_non_convex_mesh():
    from service.evaluation.run import collision_pieces

    a = trimesh.creation.box((0.1, 0.03, 0.03))
    b = trimesh.creation.box((0.03, 0.03, 0.1))
    b.apply_translation([-0.035, 0, 0.035])
    # an L made of two boxes sharing no faces: the hull fills the notch, the decomposition does not
    ell = Mesh.from_trimesh(trimesh.util.concatenate([a, b]))
    hull = collision_pieces(ell, "hull")
    assert len(hull) == 1
    pieces = collision_pieces(ell, "decompose")
    vol = sum(p.to_trimesh().volume for p in pieces)
    assert len(pieces) >= 2 and vol < 0.8 * hull[0].to_trimesh().volume


def test_trajectory_metrics_and_contact_scores_by_hand():
    from service.evaluation.run import contact_scores, trajectory_metrics

    t = np.arange(6) * 0.1
    ref = np.tile(np.eye(4), (6, 1, 1))
    sim = ref.copy()
    sim[:, 0, 3] = [0.0, 0.02, 0.05, 0.12, 0.2, 0.3]  # crosses 0.10 m at frame 3
    valid = np.array([True, True, True, False, True, True])  # frame 3 not tracked: first divergence at frame 4
    m, dp, _ = trajectory_metrics(t, sim, ref, valid, 0.10, 45.0)
    assert m["time_before_divergence_s"] == pytest.approx(0.4)
    assert m["pos_err_m"] == pytest.approx(np.mean([0.0, 0.02, 0.05, 0.2, 0.3]))
    assert np.isnan(dp[3])
    sim[:, 0, 3] = 0.01
    sim[2, :3, :3] = so3_exp(np.array([0.0, 0.0, np.radians(30)]))
    m, _, dr = trajectory_metrics(t, sim, ref, np.ones(6, bool), 0.10, 45.0)
    assert m["time_before_divergence_s"] == pytest.approx(0.5 + 1e-3)  # never: last time + 1 ms
    assert m["rot_err_deg"] == pytest.approx(30 / 6)
    a = np.array([0, 1, 1, 1, 0, 0], bool)
    b = np.array([0, 0, 1, 1, 1, 0], bool)
    s = contact_scores(a, b)
    assert s["contact_iou"] == pytest.approx(4 / 6) and s["contact_iou_jaccard"] == pytest.approx(2 / 4)
    s = contact_scores(np.zeros(6, bool), np.zeros(6, bool))
    assert s["contact_iou"] == 1.0 and s["contact_iou_jaccard"] is None and s["contact_iou_jaccard_reason"]
