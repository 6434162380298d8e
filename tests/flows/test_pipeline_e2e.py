"""Every science stage, for real, on a tiny synthetic session (reduced ``fast`` preset), through the Prefect
flow the API uses: the bundle holds the model of the method, and changing only a fusion setting recomputes
fusion and what follows, not tracking or contact learning."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from flows import jobs as J
from service.bundle import REQUIRED_FILES
from service.report.json import missing_keys


@pytest.fixture(scope="module")
def run_once(tmp_path_factory, prefect_server):
    from flows.pipeline import process_session
    from service.synth import SynthSpec, make_session

    root = tmp_path_factory.mktemp("e2e")
    sdir = make_session(SynthSpec(object="milk_carton", interaction="push", preset="tiny", seed=7),
                        root / "session").session_dir
    data = root / "data"
    res = process_session(session=str(sdir), data_dir=str(data), preset="fast", stages="all")
    return res, data


def test_every_stage_runs_and_the_bundle_is_complete(run_once):
    res, data = run_once
    job = J.JobStore(data / "jobs").get(res["job_id"])
    assert job["state"] == J.COMPLETED, job.get("error")
    for stage in ("ingest", "tracking", "contact", "fusion", "evaluation", "residuals", "bundle"):
        assert job["stages"][stage]["state"] == J.COMPLETED, (stage, job["stages"][stage])
    out = Path(res["bundle_dir"])
    for name in REQUIRED_FILES:
        assert (out / name).is_file(), name
    report = json.loads((out / "report.json").read_text())
    assert missing_keys(report) == []
    assert report["tracking"]["frames_tracked"] > 0
    assert set(report["tracking"]["masks"]) == {"trimmed_by_colour", "strip_fraction"}
    for method in ("vision_only", "physics_only", "fused"):
        assert report["geometry"][method]["chamfer_m"] is not None
        assert report["dynamics"][method]["pos_err_m"] is not None
    urdf = ET.parse(out / "object.urdf").getroot()
    link = urdf.find("link")
    assert link.get("name") == "object"
    assert float(link.find("inertial/mass").get("value")) == pytest.approx(report["model"]["mass_kg"])
    assert link.find("visual/geometry/mesh").get("filename").endswith("meshes/fused.obj")


def test_fusion_setting_change_recomputes_fusion_and_after_only(run_once):
    from flows.pipeline import process_session

    res, data = run_once
    again = process_session(session=res["sha256"], data_dir=str(data), preset="fast",
                            config={"preset": "fast", "fusion": {"seed": 1}})
    job = J.JobStore(data / "jobs").get(again["job_id"])
    cached = {s: job["stages"][s]["cached"] for s in ("tracking", "contact", "fusion", "evaluation", "residuals")}
    assert cached == {"tracking": True, "contact": True, "fusion": False, "evaluation": False, "residuals": False}
