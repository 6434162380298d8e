"""Job state on disk, the report.json skeleton and the bundle writer (no Prefect involved)."""

from __future__ import annotations

import json
import os
import zipfile

import numpy as np
import pytest

from flows.jobs import COMPLETED, FAILED, QUEUED, RUNNING, STAGE_ORDER, JobStore, ProgressBridge, new_job
from service.bundle import REQUIRED_FILES, BundleParts, write_bundle, write_trajectory_csv
from service.mesh import Mesh
from service.report.json import NOT_AVAILABLE, build_report, missing_keys
from service.transforms import make_X, so3_exp

SHA = "ab" * 32


def _job(jid: str = SHA) -> dict:
    return new_job(jid, session_sha256=jid, name="s", frames=3, preset="fast")


def test_job_lifecycle(tmp_path):
    jobs = JobStore(tmp_path / "jobs")
    job, created = jobs.create(_job())
    assert created and job["state"] == QUEUED and set(job["stages"]) == set(STAGE_ORDER)
    again, created2 = jobs.create(_job())
    assert not created2 and again["created"] == job["created"]
    assert jobs.next_queued() == SHA
    assert jobs.claim(SHA, "pid:1") and not jobs.claim(SHA, "pid:2")
    assert jobs.get(SHA)["state"] == RUNNING and jobs.get(SHA)["runner"] == "pid:1"
    jobs.stage(SHA, "tracking", state="running", fraction=0.5, message="half")
    jobs.fail(SHA, "tracking", "no object in the masks")
    j = jobs.get(SHA)
    assert j["state"] == FAILED and j["error"] == {"stage": "tracking", "reason": "no object in the masks"}
    assert j["stages"]["tracking"]["state"] == FAILED
    # a failed job is queued again by a new upload; a completed one is not
    j2, created3 = jobs.create(_job())
    assert created3 and j2["state"] == QUEUED and j2["error"] is None
    jobs.claim(SHA, "pid:1")
    jobs.finish(SHA, bundle="/x.zip")
    _, created4 = jobs.create(_job())
    assert not created4 and jobs.get(SHA)["state"] == COMPLETED
    # files are whole JSON, no temporaries left
    assert sorted(p.name for p in (tmp_path / "jobs").iterdir() if not p.name.startswith(".")) == [f"{SHA}.json"]
    assert not list((tmp_path / "jobs").glob("*.tmp"))


def test_orphaned_running_job_is_requeued(tmp_path):
    jobs = JobStore(tmp_path / "jobs")
    jobs.create(_job())
    dead = os.fork()
    if dead == 0:
        os._exit(0)
    os.waitpid(dead, 0)
    jobs.claim(SHA, f"pid:{dead}")
    jobs.create(_job("cd" * 32))
    jobs.claim("cd" * 32, f"pid:{os.getpid()}")
    assert jobs.requeue_orphans() == [SHA]
    assert jobs.get(SHA)["state"] == QUEUED and jobs.get("cd" * 32)["state"] == RUNNING


def test_invalid_job_ids(tmp_path):
    jobs = JobStore(tmp_path)
    assert jobs.get("../../etc/passwd") is None and not jobs.exists("a/b")
    with pytest.raises(ValueError):
        jobs.path("../x")


def test_progress_bridge_throttles_and_clips(tmp_path):
    jobs = JobStore(tmp_path / "jobs")
    jobs.create(_job())
    seen = []
    b = ProgressBridge(jobs, SHA, "contact", min_interval_s=3600, also=lambda f, m: seen.append((f, m)))
    b(0.1, "epoch 1")
    b(0.2, "epoch 2")  # throttled
    assert jobs.get(SHA)["stages"]["contact"]["fraction"] == pytest.approx(0.1)
    b(7.0, "done")  # clipped, and 1.0 is always written
    st = jobs.get(SHA)["stages"]["contact"]
    assert st["fraction"] == 1.0 and st["message"] == "done"
    assert seen == [(0.1, "epoch 1"), (1.0, "done")]
    ProgressBridge(None, None, "x")(float("nan"), "no job: nothing happens")


def test_report_skeleton_has_every_key_with_reasons():
    r = build_report(session={"name": "s", "sha256": SHA, "frames": 3}, timings_s={"ingest": 0.25})
    assert missing_keys(r) == []
    assert r["timings_s"]["ingest"] == 0.25 and r["timings_s"]["tracking"] is None and r["timings_s"]["total"] == 0.25
    assert r["model"]["mass_kg"] is None and r["model"]["reason"] == NOT_AVAILABLE
    assert r["tracking"]["vs_ground_truth"] is None and r["tracking"]["vs_ground_truth_reason"]
    for m in ("vision_only", "physics_only", "fused"):
        assert r["geometry"][m]["chamfer_m"] is None and r["geometry"][m]["reason"]
    for m in ("vision_only", "physics_only", "fused", "ground_truth_geometry"):
        assert r["dynamics"][m]["time_before_divergence_s"] is None and r["dynamics"][m]["reason"]
    assert r["residuals"]["accepted"] == [] and r["residuals"]["reason"]
    json.dumps(r, allow_nan=False)
    assert "model" in missing_keys({k: v for k, v in r.items() if k != "model"})


def test_trajectory_csv_roundtrip(tmp_path):
    t = np.array([0.0, 0.1, 0.2])
    X = np.stack([make_X(so3_exp(np.array([0.0, 0.0, a])), np.array([a, 2 * a, 0.1])) for a in (0.0, 0.3, -2.0)])
    X[2, :3, :3] = so3_exp(np.array([0.0, 3.0, 0.0]))  # a rotation whose quaternion may come out with w < 0
    p = write_trajectory_csv(t, X, tmp_path / "trajectory.csv")
    lines = p.read_text().splitlines()
    assert lines[0] == "t,x,y,z,qw,qx,qy,qz" and len(lines) == 4
    rows = np.loadtxt(p, delimiter=",", skiprows=1)
    np.testing.assert_allclose(rows[:, 0], t)
    np.testing.assert_allclose(rows[:, 1:4], X[:, :3, 3], atol=1e-9)
    assert np.all(rows[:, 4] >= 0)
    np.testing.assert_allclose(np.linalg.norm(rows[:, 4:], axis=1), 1.0, atol=1e-7)
    with pytest.raises(ValueError):
        write_trajectory_csv(t[:2], X, tmp_path / "bad.csv")


def test_bundle_from_partial_outputs(tmp_path):
    report = build_report(session={"name": "s", "sha256": SHA, "frames": 2}, timings_s={"ingest": 0.1})
    tet = Mesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]) * 0.05, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    parts = BundleParts(report=report, t=np.array([0.0, 0.1]), X_WO=np.stack([np.eye(4)] * 2),
                        meshes={"visible": tet}, missing={"object.urdf": "contact: stage not available yet"})
    out = write_bundle(parts, tmp_path / "b", zip_path=tmp_path / "b.zip")
    files = {p.relative_to(tmp_path / "b").as_posix() for p in (tmp_path / "b").rglob("*") if p.is_file()}
    assert {"report.json", "report.html", "trajectory.csv", "meshes/visible.obj"} <= files
    assert out["bundle"]["missing"]["object.urdf"] == "contact: stage not available yet"
    for f in REQUIRED_FILES:
        assert (f in files) != (f in out["bundle"]["missing"]), f
    assert set(zipfile.ZipFile(tmp_path / "b.zip").namelist()) == files
    on_disk = json.loads((tmp_path / "b" / "report.json").read_text())
    assert on_disk == out
    # rewriting replaces the bundle; a non-bundle folder is never replaced
    write_bundle(parts, tmp_path / "b")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "keep.txt").write_text("mine")
    with pytest.raises(FileExistsError):
        write_bundle(parts, tmp_path / "other")
    assert (tmp_path / "other" / "keep.txt").read_text() == "mine"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
