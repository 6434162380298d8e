"""Artifact store: keys, atomic writes, caching through ``flows.stages.run_cached``."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from flows.stages import StageContext, StageSpec, run_cached
from service.errors import StageFailed
from service.store import ArtifactRef, ArtifactStore, compute_key, stage_code_version, stage_files
from tests.flows import fake_stage
from tests.flows.fake_stage import FakeConfig, FakeInputs, FakeOutputs


@dataclass(frozen=True)
class Value:
    a: np.ndarray
    name: str


def test_key_depends_on_stage_code_inputs_and_config():
    k = compute_key("tracking", "c1", {"session": "aa"}, {"seed": 0})
    assert k == compute_key("tracking", "c1", {"session": "aa"}, {"seed": 0})
    assert len(k) == 64
    others = {
        compute_key("contact", "c1", {"session": "aa"}, {"seed": 0}),
        compute_key("tracking", "c2", {"session": "aa"}, {"seed": 0}),
        compute_key("tracking", "c1", {"session": "ab"}, {"seed": 0}),
        compute_key("tracking", "c1", {"session": "aa"}, {"seed": 1}),
        compute_key("tracking", "c1", {"session": "aa", "x": "aa"}, {"seed": 0}),
    }
    assert k not in others and len(others) == 5
    # input order and dataclass vs dict of the same fields do not matter
    assert compute_key("s", "c", {"a": "1", "b": "2"}, FakeConfig()) == compute_key("s", "c", {"b": "2", "a": "1"},
                                                                                     {"scale": 2.0, "fail": False})


def test_code_version_follows_the_stage_sources_and_their_imports(tmp_path):
    svc = tmp_path / "service"
    (svc / "stagex").mkdir(parents=True)
    (svc / "__init__.py").write_text("")
    (svc / "helper.py").write_text("A = 1\n")
    (svc / "unrelated.py").write_text("B = 1\n")
    (svc / "stagex" / "__init__.py").write_text("from service.helper import A\n")
    files = {p.name for p in stage_files("stagex", svc)}
    assert files == {"__init__.py", "helper.py"}
    v1 = stage_code_version("stagex", svc)
    (svc / "unrelated.py").write_text("B = 2\n")
    stage_code_version.cache_clear()
    assert stage_code_version("stagex", svc) == v1
    (svc / "helper.py").write_text("A = 2\n")
    stage_code_version.cache_clear()
    assert stage_code_version("stagex", svc) != v1
    stage_code_version.cache_clear()
    stage_files.cache_clear()


def test_real_stage_closure_includes_shared_modules():
    names = {p.relative_to(p.parents[1]).as_posix() if p.parent.name != "service" else p.name
             for p in stage_files("fusion")}
    assert "fusion/stage.py" in names and "sdf/fit.py" in names and "mesh.py" in names


def test_save_load_roundtrip_and_manifest_last(tmp_path):
    store = ArtifactStore(tmp_path / "artifacts")
    key = store.key("demo", {"session": "ab" * 32}, {"k": 1})
    assert store.get("demo", key) is None
    v = Value(np.arange(6.0).reshape(2, 3), "x")
    ref = store.save("demo", key, v, inputs={"session": "ab" * 32}, config={"k": 1}, timings={"demo": 0.5},
                     metrics={"m": np.float64(2.0)})
    assert store.has("demo", key) and Path(ref.path) == tmp_path / "artifacts" / "demo" / key
    back = store.load(Value, ref)
    np.testing.assert_array_equal(back.a, v.a)
    assert back.name == "x"
    man = json.loads((Path(ref.path) / "manifest.json").read_text())
    assert man["inputs"] == {"session": "ab" * 32} and man["config"] == {"k": 1}
    assert man["timings_s"] == {"demo": 0.5} and man["metrics"] == {"m": 2.0}
    assert man["code_version"] == store.code_version("demo")
    # nothing temporary is left
    assert [p.name for p in (tmp_path / "artifacts" / "demo").iterdir()] == [key]


def test_failed_write_leaves_nothing(tmp_path):
    store = ArtifactStore(tmp_path / "artifacts")
    key = "cd" * 32

    def write(folder: Path) -> None:
        (folder / "half.bin").write_bytes(b"x")
        raise OSError("disk full")

    with pytest.raises(OSError):
        store.put("demo", key, write, inputs={}, config={})
    assert not store.has("demo", key)
    assert list((tmp_path / "artifacts" / "demo").iterdir()) == []


def test_concurrent_writer_keeps_first_artifact(tmp_path):
    store = ArtifactStore(tmp_path / "artifacts")
    key = "ef" * 32
    store.put("demo", key, lambda f: (f / "who").write_text("first"), inputs={}, config={})
    store.put("demo", key, lambda f: (f / "who").write_text("second"), inputs={}, config={})
    assert (store.path("demo", key) / "who").read_text() == "first"
    assert store.manifest(store.ref("demo", key))["timings_s"]["demo"] >= 0.0  # default: the write's time
    assert len(list((tmp_path / "artifacts" / "demo").iterdir())) == 1


def test_bad_key_refused(tmp_path):
    with pytest.raises(ValueError):
        ArtifactStore(tmp_path).path("demo", "../etc")


SPEC = StageSpec("fake", "tests.flows.fake_stage", "tests.flows.fake_stage:FakeOutputs", (),
                 lambda ctx: FakeInputs(np.arange(4.0)))


def _ctx(store: ArtifactStore, session_key: str = "ab" * 32) -> StageContext:
    return StageContext(session=None, store=store, refs={"ingest": ArtifactRef("ingest", session_key, "/nowhere")})


def test_second_run_hits_the_cache_and_config_change_recomputes(tmp_path):
    store = ArtifactStore(tmp_path / "artifacts")
    fake_stage.CALLS["n"] = 0
    seen = []
    r1 = run_cached(SPEC, _ctx(store), FakeConfig(scale=2.0), progress=lambda f, m: seen.append((f, m)))
    assert not r1.cached and fake_stage.CALLS["n"] == 1
    assert (0.5, "halfway") in seen and seen[-1] == (1.0, "done")
    out = store.load(FakeOutputs, r1.ref)
    np.testing.assert_array_equal(out.y, np.arange(4.0) * 2)
    assert store.manifest(r1.ref)["metrics"] == {"sum": 12.0}
    # the input builder's code is part of the key (it shapes what the stage computes)
    from service.store import module_code_version

    assert store.manifest(r1.ref)["inputs"]["wiring"] == module_code_version(__name__)

    r2 = run_cached(SPEC, _ctx(store), FakeConfig(scale=2.0))
    assert r2.cached and r2.ref == r1.ref and fake_stage.CALLS["n"] == 1
    assert r2.seconds == pytest.approx(r1.seconds)

    r3 = run_cached(SPEC, _ctx(store), FakeConfig(scale=3.0))
    assert not r3.cached and r3.ref.key != r1.ref.key and fake_stage.CALLS["n"] == 2

    r4 = run_cached(SPEC, _ctx(store, "cd" * 32), FakeConfig(scale=2.0))  # other session
    assert not r4.cached and r4.ref.key not in (r1.ref.key, r3.ref.key)


def test_stage_exception_becomes_stage_failed_and_nothing_is_stored(tmp_path):
    store = ArtifactStore(tmp_path / "artifacts")
    with pytest.raises(StageFailed) as ei:
        run_cached(SPEC, _ctx(store), FakeConfig(fail=True))
    assert ei.value.stage == "fake" and "told to fail" in ei.value.reason
    assert not (tmp_path / "artifacts" / "fake").exists() or not any((tmp_path / "artifacts" / "fake").iterdir())


def test_unavailable_stage():
    spec = StageSpec("ghost", "service.report", "service.report.json:FORMAT", (), lambda ctx: None)
    assert spec.unavailable_reason() == "stage not available yet"
    assert SPEC.unavailable_reason() is None


def test_code_version_and_manifest_follow_the_runtime_libraries(tmp_path, monkeypatch):
    """A new numpy (or any of RUNTIME_PACKAGES) gives every stage a new code version, so its outputs are computed
    again instead of mixing results of two library versions; the manifest records the versions it was made with."""
    import service.store as st

    svc = tmp_path / "service"
    (svc / "stagex").mkdir(parents=True)
    (svc / "__init__.py").write_text("")
    (svc / "stagex" / "__init__.py").write_text("A = 1\n")
    here = st.runtime_versions()
    assert set(here) == {"python", *st.RUNTIME_PACKAGES} and here["numpy"] == np.__version__
    st.stage_code_version.cache_clear()
    v1 = st.stage_code_version("stagex", svc)
    monkeypatch.setattr(st, "runtime_versions", lambda: {**here, "numpy": "0.0.1"})
    st.stage_code_version.cache_clear()
    assert st.stage_code_version("stagex", svc) != v1
    store = ArtifactStore(tmp_path / "artifacts", service_dir=svc)
    ref = store.save("stagex", store.key("stagex", {}, {}), Value(np.zeros(2), "z"), inputs={}, config={})
    man = json.loads((Path(ref.path) / "manifest.json").read_text())
    assert man["runtime"]["numpy"] == "0.0.1" and man["code_version"] == store.code_version("stagex")
    st.stage_code_version.cache_clear()
    st.stage_files.cache_clear()
