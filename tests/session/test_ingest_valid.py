"""Valid sessions: every container kind, layouts, hashing, re-loading, fps vs frame_times, cam_K.txt."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from service.session import ingest, load_session, sha256_of
from tests.session.conftest import DELETE, K, Spec, pack, tree


@pytest.mark.parametrize("kind", ["zip", "tar", "tgz"])
@pytest.mark.parametrize("top", [None, "bottle_push_03"])
def test_archive_kinds_and_layouts(session_dir, tmp_path, kind, top):
    arc = pack(session_dir, tmp_path / f"up.{kind}", kind, top=top)
    dest = tmp_path / "staging" / "x"
    s = ingest(arc, dest)
    assert s.root == (dest / top if top else dest)
    assert (s.root / "session.json").is_file()
    assert s.n_frames == 4 and (s.width, s.height) == (32, 24)
    assert s.sha256 == sha256_of(arc)
    assert all(p.is_file() and dest in p.parents for p in s.rgb_files + s.depth_files + s.mask_files)
    assert s.name == "tiny_push"
    assert s.friction.object_table == 0.3 and s.friction.object_robot == 0.1
    assert s.mass is None and not s.has_ground_truth
    np.testing.assert_allclose(s.K, K)
    assert s.depth(0).dtype == np.float32 and s.depth(0).shape == (24, 32)
    assert s.mask(0).any() and s.rgb(0).shape == (24, 32, 3)


def test_folder_source_is_copied_and_source_untouched(session_dir, tmp_path):
    before = tree(session_dir)
    dest = tmp_path / "dest"
    s = ingest(session_dir, dest)
    assert s.root == dest
    assert tree(session_dir) == before
    assert (dest / "robot.csv").read_bytes() == (session_dir / "robot.csv").read_bytes()


def test_empty_existing_dest_is_accepted_nonempty_refused(session_dir, tmp_path):
    dest = tmp_path / "d"
    dest.mkdir()
    ingest(session_dir, dest)
    with pytest.raises(FileExistsError):
        ingest(session_dir, dest)


def test_sha256_of_folder_is_content_based(make, tmp_path):
    a = make(name="a")
    b = tmp_path / "b"
    shutil.copytree(a, b)
    assert sha256_of(a) == sha256_of(b)
    (b / "extra.txt").write_text("x")
    assert sha256_of(a) != sha256_of(b)
    (b / "extra.txt").unlink()
    (b / "robot.csv").write_text((b / "robot.csv").read_text() + "\n")
    assert sha256_of(a) != sha256_of(b)


def test_load_session_matches_ingest(make, tmp_path):
    src = make(Spec(noise=0.001, meta={"table": {"height": None}}))
    s = ingest(src, tmp_path / "d")
    r = load_session(s.root, s.sha256)
    assert r.table_height == s.table_height and r.table_height_detected
    assert r.name == s.name and r.rgb_files == s.rgb_files
    np.testing.assert_array_equal(r.p_WE, s.p_WE)
    np.testing.assert_array_equal(r.frame_times, s.frame_times)
    np.testing.assert_array_equal(r.X_WC, s.X_WC)


def test_fps_gives_frame_times(make, tmp_path):
    s = ingest(make(Spec(fps=20.0, n=5)), tmp_path / "d")
    np.testing.assert_allclose(s.frame_times, np.arange(5) / 20.0)


def test_explicit_frame_times(make, tmp_path):
    ft = [0.0, 0.11, 0.19, 0.32]
    s = ingest(make(Spec(meta={"fps": None, "frame_times": ft})), tmp_path / "d")
    np.testing.assert_allclose(s.frame_times, ft)


def test_cam_K_txt_fallback(make, tmp_path):
    src = make(Spec(meta={"camera": {"K": DELETE}}))
    K2 = K.copy()
    K2[0, 0] = K2[1, 1] = 41.5
    (src / "cam_K.txt").write_text("\n".join(" ".join(f"{x:.6f}" for x in r) for r in K2))
    s = ingest(src, tmp_path / "d")
    np.testing.assert_allclose(s.K, K2)


def test_session_json_K_wins_over_cam_K_txt(make, tmp_path):
    src = make()
    (src / "cam_K.txt").write_text("1 0 0\n0 1 0\n0 0 1\n")
    s = ingest(src, tmp_path / "d")
    np.testing.assert_allclose(s.K, K)


def test_png_rgb_and_extra_keys_and_ground_truth(make, tmp_path):
    src = make(Spec(rgb_ext=".png", meta={"future_field": {"a": 1}, "object": {"mass": 0.4, "colour": "red"}}))
    (src / "ground_truth").mkdir()
    (src / "ground_truth" / "poses.csv").write_text("t,x,y,z,qw,qx,qy,qz\n")
    (src / "README.txt").write_text("notes")
    s = ingest(src, tmp_path / "d")
    assert s.mass == 0.4 and s.has_ground_truth
    assert all(p.suffix == ".png" for p in s.rgb_files)


def test_name_defaults(make, tmp_path):
    src = make(Spec(meta={"name": DELETE}))
    arc = pack(src, tmp_path / "cup_03.tar.gz", "tgz")
    assert ingest(arc, tmp_path / "d1").name == "cup_03"
    arc2 = pack(src, tmp_path / "x.zip", "zip", top="mug_7")
    assert ingest(arc2, tmp_path / "d2").name == "mug_7"


def test_macos_litter_is_skipped(session_dir, tmp_path):
    import zipfile

    arc = pack(session_dir, tmp_path / "a.zip", "zip", top="s")
    with zipfile.ZipFile(arc, "a") as zf:
        zf.writestr("__MACOSX/s/._session.json", b"junk")
        zf.writestr("s/rgb/.DS_Store", b"junk")
    s = ingest(arc, tmp_path / "d")
    assert not (tmp_path / "d" / "__MACOSX").exists()
    assert s.n_frames == 4


def test_progress_is_reported(session_dir, tmp_path):
    seen = []
    ingest(session_dir, tmp_path / "d", progress=lambda f, m: seen.append((f, m)))
    fr = [f for f, _ in seen]
    assert fr == sorted(fr) and fr[-1] == 1.0 and all(isinstance(m, str) for _, m in seen)


def test_session_json_is_copied_verbatim(session_dir, tmp_path):
    s = ingest(session_dir, tmp_path / "d")
    assert json.loads((s.root / "session.json").read_text())["format"] == "vysics-session/1"


def test_dest_inside_source_folder_is_refused(session_dir):
    with pytest.raises(ValueError):
        ingest(session_dir, session_dir / "staging")
    assert not (session_dir / "staging").exists()


def test_load_session_survives_a_broken_sidecar(make, tmp_path):
    s = ingest(make(Spec(meta={"table": {"height": None}})), tmp_path / "d")
    (s.root / ".vysics-ingest.json").write_text("{not json")
    r = load_session(s.root, s.sha256)
    assert r.table_height_detected and abs(r.table_height - s.table_height) < 1e-3
