import csv
import json

import pytest

from service.evaluation.bench import default_specs, run_bench
from service.synth import OBJECT_KINDS, SynthSpec

CHAMFER = {"vision_only": 0.03, "physics_only": 0.02, "fused": 0.01}


def fake_report(scale: float) -> dict:
    geo = {m: {"chamfer_m": c * scale, "iou": 1 - c * 10 * scale} for m, c in CHAMFER.items()}
    dyn = {m: {"pos_err_m": 0.05 * scale, "rot_err_deg": 10.0, "time_before_divergence_s": 2.0,
               "time_before_divergence_frac": 0.5 * scale, "contact_iou": 0.8}
           for m in ("vision_only", "physics_only", "fused", "ground_truth_geometry")}
    return {"format": "vysics-report/1", "geometry": geo, "dynamics": dyn}


def make_dirs(root, names):
    for n in names:
        (root / n).mkdir(parents=True)
        (root / n / "session.json").write_text(json.dumps({"name": n}))


def test_tables_average_per_object_and_overall(tmp_path):
    make_dirs(tmp_path / "s", ["egg_push_000", "egg_pivot_001", "mug_push_000", "mug_topple_004"])
    scale = {"egg_push_000": 1.0, "egg_pivot_001": 2.0, "mug_push_000": 1.0, "mug_topple_004": None}

    def process(d):
        if scale[d.name] is None:
            raise RuntimeError("tracking lost")
        return fake_report(scale[d.name])

    res = run_bench(tmp_path / "s", tmp_path / "out", process=process)
    assert [f["session"] for f in res.failures] == ["mug_topple_004"] and "tracking lost" in res.failures[0]["error"]
    with open(res.tables["chamfer_csv"]) as fh:
        table = {r["method"]: r for r in csv.DictReader(fh)}
    assert float(table["fused"]["egg"]) == pytest.approx(1.5)  # cm: mean of 1 and 2
    assert float(table["fused"]["mug"]) == pytest.approx(1.0)
    assert float(table["vision_only"]["all"]) == pytest.approx(100 * 0.03 * 4 / 3)
    md = res.tables["chamfer_md"].read_text()
    assert "| fused | **1.50** | **1.00** | **1.33** |" in md
    assert set(res.plots) >= {"chamfer", "iou", "divergence", "pos_err"}
    assert all(p.is_file() for p in res.plots.values())
    assert (tmp_path / "out" / "reports" / "egg_push_000.json").is_file()
    assert json.loads((tmp_path / "out" / "bench.json").read_text())["failures"][0]["session"] == "mug_topple_004"


def test_synthetic_specs_are_generated_once(tmp_path):
    seen = []

    def process(d):
        assert (d / "session.json").is_file() and (d / "ground_truth" / "mesh.obj").is_file()
        seen.append(d.name)
        return fake_report(1.0)

    spec = SynthSpec(object="prism", interaction="push", seed=3, preset="tiny", n_frames=20)
    res = run_bench([spec], tmp_path, process=process)
    assert seen == ["prism_push_003"] and res.rows[0]["object"] == "prism"
    mtime = (tmp_path / "sessions" / "prism_push_003" / "session.json").stat().st_mtime_ns
    run_bench([spec], tmp_path, process=process)
    assert (tmp_path / "sessions" / "prism_push_003" / "session.json").stat().st_mtime_ns == mtime


def test_default_specs_cover_every_object_kind():
    specs = default_specs("small", seeds=(0, 1))
    assert {s.object for s in specs} == set(OBJECT_KINDS)
    assert {s.interaction for s in specs} == {"push", "pivot", "topple"}
    assert all(s.occlusion == "heavy" for s in specs) and len(specs) == 2 * len(OBJECT_KINDS)


def test_dynamics_table_bolds_the_best_competitor_only(tmp_path):
    make_dirs(tmp_path / "s", ["egg_push_000"])

    def process(d):
        rep = fake_report(1.0)
        rep["dynamics"]["fused"]["pos_err_m"] = 0.02
        rep["dynamics"]["ground_truth_geometry"]["pos_err_m"] = 0.001
        return rep

    res = run_bench(tmp_path / "s", tmp_path / "out", process=process)
    md = res.tables["dynamics_md"].read_text()
    assert "| fused | **2.00** |" in md and "| ground_truth_geometry | 0.10 |" in md
    assert md.rstrip().endswith("| 1 |")  # the session count is an integer
