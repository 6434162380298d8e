"""The synthetic sessions follow vysics-session/1 and pass the service's own ingest."""

import json

import cv2
import numpy as np

from service.session import ingest
from service.synth import make_archive


def _check_folder(root, n_frames, width, height):
    s = json.loads((root / "session.json").read_text())
    assert s["format"] == "vysics-session/1"
    K = np.asarray(s["camera"]["K"])
    assert K.shape == (3, 3) and K[2, 2] == 1.0
    X = np.asarray(s["camera"]["T_world_camera"])
    assert np.allclose(X[:3, :3] @ X[:3, :3].T, np.eye(3), atol=1e-9) and np.isclose(np.linalg.det(X[:3, :3]), 1.0)
    rgb = sorted((root / "rgb").iterdir())
    assert len(rgb) == n_frames
    for sub in ("depth", "masks"):
        assert [p.stem for p in sorted((root / sub).iterdir())] == [p.stem for p in rgb]
    d = cv2.imread(str(root / "depth" / "000000.png"), cv2.IMREAD_UNCHANGED)
    assert d.dtype == np.uint16 and d.shape == (height, width)
    m = cv2.imread(str(root / "masks" / "000000.png"), cv2.IMREAD_UNCHANGED)
    assert m.dtype == np.uint8 and m.shape == (height, width) and (m > 0).sum() > 20  # the object is in view
    header = (root / "robot.csv").read_text().splitlines()[0]
    assert header == "t,ee_x,ee_y,ee_z,cmd_x,cmd_y,cmd_z"
    r = np.loadtxt(root / "robot.csv", delimiter=",", skiprows=1)
    assert np.all(np.diff(r[:, 0]) > 0)
    for f in ("mesh.obj", "poses.csv", "contacts.csv"):
        assert (root / "ground_truth" / f).is_file()
    p = np.loadtxt(root / "ground_truth" / "poses.csv", delimiter=",", skiprows=1)
    assert p.shape == (n_frames, 8)
    assert np.allclose(np.linalg.norm(p[:, 4:8], axis=1), 1.0, atol=1e-6)
    return s


def test_clean_session_layout_and_ingest(clean_tiny, tmp_path):
    spec, res = clean_tiny
    s = _check_folder(res.session_dir, 60, 160, 120)
    assert s["object"]["mass"] is not None and s["table"]["height"] == 0.0
    sess = ingest(res.session_dir, tmp_path / "ing")
    assert sess.n_frames == 60 and sess.width == 160
    assert np.allclose(sess.X_WC, np.asarray(s["camera"]["T_world_camera"]))
    assert len(res.contacts) >= 1  # the robot touched the object


def test_noisy_session_ingests_with_undeclared_values(noisy_tiny, tmp_path):
    spec, res = noisy_tiny
    s = _check_folder(res.session_dir, 60, 160, 120)
    assert s["object"]["mass"] is None and s["table"]["height"] is None
    sess = ingest(res.session_dir, tmp_path / "ing")
    truth = json.loads(res.sidecar_path.read_text())["true"]
    assert sess.table_height_detected
    assert abs(sess.table_height - truth["table_height"]) < 0.01


def test_archives_ingest(clean_tiny, tmp_path):
    _, res = clean_tiny
    for name in ("s.zip", "s.tar.gz"):
        a = make_archive(res.session_dir, tmp_path / name)
        sess = ingest(a, tmp_path / f"ing_{name}")
        assert sess.n_frames == 60
        again = make_archive(res.session_dir, tmp_path / f"again_{name}")
        assert again.read_bytes() == a.read_bytes()  # deterministic archives


def test_sidecar_outside_session_and_not_leaked(noisy_tiny):
    spec, res = noisy_tiny
    side = res.sidecar_path
    assert side.is_file() and side.parent == res.session_dir.parent
    assert res.session_dir not in side.parents
    truth = json.loads(side.read_text())
    assert truth["effects"]["restitution"] == 0.3 and truth["true"]["friction_object_table"] == 0.4
    text = (res.session_dir / "session.json").read_text()
    assert "restitution" not in text and "effects" not in text and "0.4" not in json.dumps(json.loads(text)["friction"])
    assert not any("effects" in p.name for p in res.session_dir.rglob("*"))
    # the robot clock is shifted by the hidden offset: samples sit at k / 240 + 0.0432 s
    r = np.loadtxt(res.session_dir / "robot.csv", delimiter=",", skiprows=1)
    phase = ((r[:, 0] - 0.0432) * 240.0 + 0.5) % 1.0 - 0.5
    assert np.abs(phase).max() < 1e-3
    assert r[0, 0] < 0.0 and r[-1, 0] > 59 / 30.0


def test_bad_specs_are_refused(tmp_path):
    import pytest

    from service.synth import HiddenEffects, SynthSpec, describe, make_session

    with pytest.raises(ValueError, match="com_offset"):
        HiddenEffects(com_offset=0.01)
    with pytest.raises(ValueError, match="restitution"):
        HiddenEffects(restitution=1.5)
    for bad in (dict(object="teapot"), dict(interaction="throw"), dict(preset="huge"), dict(occlusion="total"), dict(occlusion=0.95)):
        with pytest.raises(ValueError):
            make_session(SynthSpec(**bad), tmp_path / "x")
    assert not (tmp_path / "x").exists()
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "keep.txt").write_text("not a session")
    with pytest.raises(FileExistsError):
        make_session(SynthSpec(n_frames=3), tmp_path / "busy")
    d = describe()
    assert set(d["objects"]) >= {"baking_box", "bottle", "egg", "milk_carton", "oat_carton", "styrofoam", "prism", "l_block"}
    assert d["presets"]["full"]["width"] == 640 and d["presets"]["tiny"]["n_frames"] == 60


def test_progress_reaches_one(tmp_path):
    from service.synth import SynthSpec, make_session

    seen = []
    make_session(SynthSpec(n_frames=6, noise=False), tmp_path / "p", progress=lambda f, m: seen.append((f, m)))
    fr = [f for f, _ in seen]
    assert fr[-1] == 1.0 and all(0.0 <= f <= 1.0 for f in fr) and fr == sorted(fr)


def test_camera_sides(tmp_path):
    from service.synth import SynthSpec, make_session

    for side in ("front", "other_side"):
        r = make_session(SynthSpec(n_frames=4, noise=False, camera_side=side, occlusion="heavy"), tmp_path / side)
        X = np.asarray(json.loads((r.session_dir / "session.json").read_text())["camera"]["T_world_camera"])
        look = X[:3, 2]
        assert (look[0] < -0.5) if side == "front" else (look[1] < -0.5)
        m = cv2.imread(str(r.session_dir / "masks" / "000000.png"), cv2.IMREAD_UNCHANGED)
        assert (m > 0).sum() > 20 and 0.3 < r.occlusion_mean < 0.8
