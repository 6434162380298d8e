"""Evaluation on a session of the synthetic lab: the true model must reproduce the true motion."""

import json

import numpy as np
import pytest

from service.evaluation import EvaluationConfig, EvaluationInputs, load_ground_truth, run
from service.mesh import Mesh
from service.model import ObjectModel
from service.session import ingest
from service.synth import SynthSpec, make_session
from service.synth.objects import make_object
from service.transforms import X_inv, make_X, so3_exp, transform_points


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("synth")
    res = make_session(SynthSpec(object="baking_box", interaction="push", seed=1, preset="tiny", noise=False), tmp / "raw")
    s = ingest(res.session_dir, tmp / "ingested")
    true = json.loads(res.sidecar_path.read_text())["true"]
    obj = make_object("baking_box")
    X_MO = make_X(so3_exp(np.array([0.0, 0.0, 0.3])), [0.01, 0.0, -0.005])  # O differs from the mesh frame
    X_OM = X_inv(X_MO)
    to_O = lambda m: Mesh(transform_points(X_OM, np.asarray(m.vertices)), np.asarray(m.faces))  # noqa: E731
    com = transform_points(X_OM, np.asarray(true["com_mesh"])[None])[0]
    inertia = X_OM[:3, :3] @ np.asarray(true["inertia_mesh"]) @ X_OM[:3, :3].T
    model = ObjectModel(to_O(obj.mesh), tuple(to_O(p) for p in obj.parts), true["mass"], True, com, inertia, s.friction, {})
    gt = load_ground_truth(s.root)
    X_WO = gt.X_WG @ X_MO
    # a deliberately wrong model: half as long along the push
    small = ObjectModel(to_O(obj.mesh), tuple(Mesh(0.6 * np.asarray(p.vertices), p.faces) for p in model.collision),
                        true["mass"], True, 0.6 * com, inertia, s.friction, {})
    inp = EvaluationInputs(s, s.frame_times, X_WO, np.ones(len(X_WO), bool),
                           {"fused": model.visual, "vision_only": small.collision[0]}, {"fused": model, "vision_only": small})
    return run(inp, EvaluationConfig.fast()), res


def test_true_model_reproduces_the_synthetic_motion(evaluated):
    out, res = evaluated
    assert res.object_travel > 0.02  # the object really moved
    for m in ("fused", "ground_truth_geometry"):
        d = out.dynamics[m]
        assert d["robot_mode"] == "impedance"
        assert d["pos_err_m"] < 0.005 and d["rot_err_deg"] < 2.0
        assert d["contact_iou"] > 0.9
    assert out.dynamics["vision_only"]["pos_err_m"] > 2 * out.dynamics["fused"]["pos_err_m"]


def test_true_geometry_scores_near_perfect(evaluated):
    out, _ = evaluated
    assert out.geometry["fused"]["chamfer_m"] < 0.004
    assert out.geometry["fused"]["iou"] > 0.9
    assert out.geometry["vision_only"]["iou"] < 0.5
    assert out.tracking["trans_err_m_max"] < 1e-9
