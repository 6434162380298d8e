"""The ``vysics`` command line: synth, run (through the Prefect flow), errors, lazy imports."""

from __future__ import annotations

import json
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from service.bundle import REQUIRED_FILES
from service.report.json import missing_keys
from workers.cli import main


def test_help_is_light():
    code = ("import sys, workers.cli; heavy = [m for m in ('torch', 'prefect', 'service.synth', 'cv2') "
            "if m in sys.modules]; print(heavy); sys.exit(1 if heavy else 0)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    r = subprocess.run([sys.executable, "-m", "workers.cli", "--help"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "synth" in r.stdout and "fit-dynamics" in r.stdout


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> tuple[Path, Path]:
    d = tmp_path_factory.mktemp("cli")
    rc = main(["synth", "--preset", "tiny", "--frames", "5", "--seed", "3", "--out", str(d / "s"),
               "--archive", str(d / "s.tar.gz")])
    assert rc == 0
    return d / "s", d / "s.tar.gz"


def test_synth_writes_folder_and_archive(session):
    folder, archive = session
    assert (folder / "session.json").is_file() and len(list((folder / "rgb").iterdir())) == 5
    assert archive.is_file() and archive.stat().st_size > 0


def test_synth_offers_every_interaction_of_the_lab():
    from service.synth.types import INTERACTIONS
    from workers.cli import build_parser

    synth = build_parser()._subparsers._group_actions[0].choices["synth"]
    action = next(a for a in synth._actions if a.dest == "interaction")
    assert tuple(action.choices) == INTERACTIONS


def test_synth_bad_effect(tmp_path, capsys):
    assert main(["synth", "--effect", "nonsense", "--out", str(tmp_path / "x")]) == 2
    assert "NAME=VALUE" in capsys.readouterr().err


def test_run_writes_the_bundle_and_reuses_the_store(session, tmp_path, prefect_server):
    folder, archive = session
    data = tmp_path / "data"
    out = tmp_path / "bundle"
    assert main(["run", str(folder), "--out", str(out), "--data-dir", str(data), "--preset", "fast", "--stages", "none", "--quiet"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert missing_keys(report) == []
    assert report["session"]["frames"] == 5 and report["timings_s"]["ingest"] > 0
    present = {p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()}
    for f in REQUIRED_FILES:
        assert f in present or report["bundle"]["missing"].get(f), f
    job = json.loads(next((data / "jobs").glob("*.json")).read_text())
    assert job["state"] == "completed" and job["id"] == report["session"]["sha256"]
    zip_path = Path(job["bundle"])
    assert set(zipfile.ZipFile(zip_path).namelist()) >= {"report.json", "report.html"}

    # running the folder again: nothing is recomputed, the bundle artifact is the same
    out3 = tmp_path / "bundle3"
    assert main(["run", str(folder), "--out", str(out3), "--data-dir", str(data), "--preset", "fast", "--stages", "none", "--quiet"]) == 0
    job3 = json.loads((data / "jobs" / f"{report['session']['sha256']}.json").read_text())
    assert job3["bundle"] == job["bundle"]
    assert job3["stages"]["bundle"]["cached"] is True and job3["stages"]["ingest"]["cached"] is True
    assert (out3 / "report.json").read_text() == (out / "report.json").read_text()


def test_run_bad_session_prints_file_and_rule(tmp_path, capsys, prefect_server):
    bad = tmp_path / "bad"
    (bad / "rgb").mkdir(parents=True)
    (bad / "session.json").write_text("{not json")
    rc = main(["run", str(bad), "--out", str(tmp_path / "o"), "--data-dir", str(tmp_path / "data"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert rc == 2
    assert err.startswith("session.json: ") and len(err) > len("session.json: ")
    assert not (tmp_path / "o").exists()
    sessions = tmp_path / "data" / "sessions"
    assert not sessions.exists() or not any(sessions.iterdir())


def test_fit_dynamics_missing_file(tmp_path, capsys):
    rc = main(["fit-dynamics", str(tmp_path / "none.npz"), "--out", str(tmp_path / "o")])
    assert rc in (2, 3)
    assert capsys.readouterr().err.strip()


def test_run_bad_config_and_stages(session, tmp_path, capsys):
    folder, _ = session
    cfg = tmp_path / "cfg.json"
    cfg.write_text("{nope")
    args = ["run", str(folder), "--out", str(tmp_path / "o"), "--data-dir", str(tmp_path / "d"), "--quiet"]
    assert main(args + ["--config", str(cfg)]) == 2
    assert capsys.readouterr().err.startswith(f"{cfg}: invalid JSON")
    cfg.write_text('{"tracking": {"no_such_field": 1}}')
    assert main(args + ["--config", str(cfg)]) == 2
    assert "no_such_field" in capsys.readouterr().err
    assert main(args + ["--stages", "tracking,warp"]) == 2
    assert "warp" in capsys.readouterr().err
    assert main(["run", str(tmp_path / "missing"), "--out", str(tmp_path / "o")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_fit_dynamics_runs_contact_and_residual_tasks(tmp_path, prefect_server):
    """Simulated tosses of a known box -> physible mesh, inertia, report with the residual-loop block."""
    import numpy as np

    from tests.contact.synthetic import tosses

    trajs = tosses(6, 40, 0.01, seed=1)
    states = np.concatenate(trajs)
    offsets = np.concatenate([[0], np.cumsum([len(t) for t in trajs])])
    data = tmp_path / "tosses" / "data.npz"
    data.parent.mkdir()
    np.savez(data, states=states, offsets=offsets)
    (data.parent / "meta.json").write_text(json.dumps({"name": "box_tosses", "dt_s": 0.01}))
    out = tmp_path / "fit"
    rc = main(["fit-dynamics", str(data), "--out", str(out), "--preset", "fast", "--mass", "0.3"])
    assert rc == 0
    for name in ("physible.obj", "inertia.json", "report.json", "residuals.json", "plots/residuals_by_mode.png"):
        assert (out / name).is_file(), name
    rep = json.loads((out / "report.json").read_text())
    assert rep["mass_kg"] == 0.3 and rep["mass_declared"] is True
    res = rep["residuals"]
    assert {"candidates", "accepted", "error_before", "error_after"} <= set(res)
    assert all(c["effect"] and isinstance(c["accepted"], bool) for c in res["candidates"])


@pytest.mark.parametrize("args,needle", [(["--seeds", "a,b"], "--seeds"), (["--objects", "teapot"], "--objects: unknown")])
def test_bench_refuses_bad_selection(tmp_path, capsys, args, needle):
    assert main(["bench", "--out", str(tmp_path / "b"), "--data-dir", str(tmp_path / "d"), *args]) == 2
    assert needle in capsys.readouterr().err
