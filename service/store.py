"""Content-addressed artifact store: ``<root>/<stage>/<key>/`` holding a stage's output value and manifest.

A stage's output is identified by

    key = sha256(stage, code version of the stage, input keys, config json)

where the code version is a hash of the stage's source files (``service/<stage>/**/*.py`` and, transitively,
every ``service`` module they import — Prefect's own task-source hashing would not see those) and of the versions of
Python and the numerical libraries the stages compute with (:func:`runtime_versions`: an upgrade of one of them can
change a stage's output in its last digits, so it recomputes rather than mixes old and new results), the input keys
are the keys of the upstream artifacts (or the upload's sha256 for ingest) and the config is the stage's
config dataclass as canonical JSON. Same inputs, same code, same config: same key, and the stored output is
reused. Any change to one of them gives a new key (the old artifact stays, nothing is overwritten).

Writes are atomic: the value is written into a temporary folder next to its final place, ``manifest.json``
(inputs, config, code version, timings, metrics) is written last, and the folder is renamed into place.
An artifact exists when ``<stage>/<key>/manifest.json`` exists; a crashed write leaves only a ``.tmp-*``
folder, never a half artifact. Values go through ``service.io.save_value`` / ``load_value``.
"""

from __future__ import annotations

import ast
import dataclasses
import hashlib
import json
import os
import shutil
import time
import uuid
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from service.io import load_value, save_value

T = TypeVar("T")

MANIFEST = "manifest.json"
VALUE_DIR = "value"
SERVICE_DIR = Path(__file__).resolve().parent

# Stages whose code lives in a subpackage named differently from the stage.
STAGE_PACKAGES: dict[str, str] = {"ingest": "session"}


def _canonical(obj: Any) -> Any:
    """A JSON-able, deterministic form of a config (dataclasses, dicts, arrays, tuples, paths)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: _canonical(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, Mapping):
        return {str(k): _canonical(v) for k, v in sorted(obj.items(), key=lambda kv: str(kv[0]))}
    if isinstance(obj, (list, tuple)):
        return [_canonical(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _canonical(obj.tolist())
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, float) and not np.isfinite(obj):
        return repr(obj)
    return obj


def config_json(config: Any) -> str:
    """Canonical JSON of a stage config (sorted keys, no whitespace)."""
    return json.dumps(_canonical(config), sort_keys=True, separators=(",", ":"))


# the libraries whose arithmetic a stage's output depends on (numerics, features, meshes, simulation)
RUNTIME_PACKAGES = ("numpy", "scipy", "torch", "opencv-python-headless", "trimesh", "scikit-image", "pybullet", "rtree")


@lru_cache(maxsize=1)
def runtime_versions() -> dict[str, str]:
    """``{"python": "3.11.7", "numpy": "2.4.6", …}`` for :data:`RUNTIME_PACKAGES` ("missing" when a package is
    not installed). Part of every stage's code version and written into each manifest (``runtime``)."""
    import platform
    from importlib import metadata

    def version(p: str) -> str:
        try:
            return metadata.version(p)
        except metadata.PackageNotFoundError:
            return "missing"

    return {"python": platform.python_version(), **{p: version(p) for p in RUNTIME_PACKAGES}}


def _hash_files(files: list[Path] | tuple[Path, ...], base: Path, *, runtime: bool = True) -> str:
    """sha256 of the files (their paths under ``base``, or their names outside it, and contents) and, with
    ``runtime``, of :func:`runtime_versions`."""
    h = hashlib.sha256()
    for f in sorted(files):
        h.update((f.relative_to(base).as_posix() if f.is_relative_to(base) else f.name).encode() + b"\0")
        h.update(hashlib.sha256(f.read_bytes()).digest())
    if runtime:
        h.update(json.dumps(runtime_versions(), sort_keys=True).encode())
    return h.hexdigest()


def _module_file(module: str, service_dir: Path) -> Path | None:
    """File of ``service.a.b`` (``a/b.py`` or ``a/b/__init__.py``) or None."""
    parts = module.split(".")[1:]
    base = service_dir.joinpath(*parts) if parts else service_dir
    if base.with_suffix(".py").is_file():
        return base.with_suffix(".py")
    if (base / "__init__.py").is_file():
        return base / "__init__.py"
    return None


def _imported_modules(path: Path, module: str) -> set[str]:
    """``service.*`` modules imported by the file ``path`` (module name ``module``), including lazy imports."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_pkg = path.name == "__init__.py"
    package = module if is_pkg else module.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.split(".")[0] == "service")
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            if mod.split(".")[0] != "service":
                continue
            out.add(mod)
            out.update(f"{mod}.{a.name}" for a in node.names)  # `from service.x import submodule`
    return out


@lru_cache(maxsize=None)
def stage_files(stage: str, service_dir: Path = SERVICE_DIR) -> tuple[Path, ...]:
    """Source files a stage runs: ``service/<package>/**/*.py`` and every ``service`` module they import,
    transitively (imports inside functions included)."""
    pkg = STAGE_PACKAGES.get(stage, stage)
    todo: list[tuple[Path, str]] = []
    d = service_dir / pkg
    if d.is_dir():
        for p in sorted(d.rglob("*.py")):
            if "__pycache__" in p.parts:
                continue
            rel = p.relative_to(service_dir).with_suffix("").parts
            mod = ".".join(("service",) + (rel[:-1] if rel[-1] == "__init__" else rel))
            todo.append((p, mod))
    elif (service_dir / f"{pkg}.py").is_file():
        todo.append((service_dir / f"{pkg}.py", f"service.{pkg}"))
    return _closure(todo, service_dir)


def _closure(todo: list[tuple[Path, str]], service_dir: Path) -> tuple[Path, ...]:
    """The files of ``todo`` and every ``service`` module they import, transitively."""
    seen: dict[Path, str] = {}
    while todo:
        path, mod = todo.pop()
        if path in seen:
            continue
        seen[path] = mod
        for dep in _imported_modules(path, mod):
            f = _module_file(dep, service_dir)
            if f is not None and f not in seen:
                todo.append((f, dep))
            # a package's __init__ runs whenever one of its submodules is imported
            parent = dep.rpartition(".")[0]
            while parent and parent != "service":
                pf = _module_file(parent, service_dir)
                if pf is not None and pf not in seen:
                    todo.append((pf, parent))
                parent = parent.rpartition(".")[0]
    return tuple(sorted(seen))


@lru_cache(maxsize=None)
def module_code_version(module: str, service_dir: Path = SERVICE_DIR) -> str:
    """sha256 of an importable module's file (e.g. ``flows.stages``, which maps stage outputs to the next
    stage's inputs) and every ``service`` module it imports, transitively."""
    import importlib.util

    spec = importlib.util.find_spec(module)
    if spec is None or not spec.origin:
        raise ValueError(f"module {module!r} not found")
    # the runtime is in the stage code versions already: a wiring input need not carry it again
    return _hash_files(_closure([(Path(spec.origin), module)], service_dir), service_dir.parent, runtime=False)


@lru_cache(maxsize=None)
def stage_code_version(stage: str, service_dir: Path = SERVICE_DIR) -> str:
    """sha256 of the stage's source files (:func:`stage_files`): any edit to code the stage runs changes it.

    Cached per process: the code does not change under a running flow.
    """
    return _hash_files(list(stage_files(stage, service_dir)), service_dir)


def compute_key(stage: str, code_version: str, inputs: Mapping[str, str], config: Any) -> str:
    """``sha256(stage, code version, input keys, config json)`` as hex."""
    payload = json.dumps(
        {"stage": stage, "code": code_version, "inputs": dict(sorted(inputs.items())), "config": config_json(config)},
        sort_keys=True,
        separators=(",", ":"),
    )
    return hashlib.sha256(payload.encode()).hexdigest()


@dataclass(frozen=True)
class ArtifactRef:
    """A reference to a stored artifact: what tasks pass between each other (never the arrays)."""

    stage: str
    key: str
    path: str  # absolute folder of the artifact

    @property
    def value_dir(self) -> Path:
        return Path(self.path) / VALUE_DIR

    @property
    def manifest_path(self) -> Path:
        return Path(self.path) / MANIFEST


class ArtifactStore:
    """The on-disk store rooted at ``root`` (``VYSICS_DATA_DIR/artifacts``)."""

    def __init__(self, root: Path, *, service_dir: Path = SERVICE_DIR):
        self.root = Path(root)
        self.service_dir = Path(service_dir)

    # ------------------------------------------------------------------ keys
    def code_version(self, stage: str) -> str:
        return stage_code_version(stage, self.service_dir)

    def key(self, stage: str, inputs: Mapping[str, str], config: Any) -> str:
        return compute_key(stage, self.code_version(stage), inputs, config)

    # ------------------------------------------------------------------ lookup
    def path(self, stage: str, key: str) -> Path:
        if not key or any(c not in "0123456789abcdef" for c in key):
            raise ValueError(f"artifact key must be lowercase hex, got {key!r}")
        return self.root / stage / key

    def ref(self, stage: str, key: str) -> ArtifactRef:
        return ArtifactRef(stage, key, str(self.path(stage, key)))

    def has(self, stage: str, key: str) -> bool:
        return (self.path(stage, key) / MANIFEST).is_file()

    def get(self, stage: str, key: str) -> ArtifactRef | None:
        return self.ref(stage, key) if self.has(stage, key) else None

    def manifest(self, ref: ArtifactRef) -> dict:
        return json.loads(ref.manifest_path.read_text())

    def load(self, cls: type[T], ref: ArtifactRef) -> T:
        return load_value(cls, ref.value_dir)

    # ------------------------------------------------------------------ writing
    def put(
        self,
        stage: str,
        key: str,
        write: Callable[[Path], None],
        *,
        inputs: Mapping[str, str],
        config: Any,
        timings: Mapping[str, float] | None = None,
        metrics: Mapping[str, Any] | None = None,
        extra: Mapping[str, Any] | None = None,
    ) -> ArtifactRef:
        """Store an artifact: ``write(folder)`` fills a temporary folder, the manifest goes in last, and the
        folder is renamed to ``<stage>/<key>``. If another writer got there first, its artifact is kept.
        ``timings`` default to ``{stage: seconds write took}``."""
        final = self.path(stage, key)
        final.parent.mkdir(parents=True, exist_ok=True)
        tmp = final.parent / f".tmp-{key[:16]}-{uuid.uuid4().hex[:8]}"
        tmp.mkdir()
        try:
            t0 = time.perf_counter()
            write(tmp)
            if timings is None:  # default: how long ``write`` took, under the stage's name
                timings = {stage: time.perf_counter() - t0}
            manifest = {
                "stage": stage,
                "key": key,
                "code_version": self.code_version(stage),
                "runtime": runtime_versions(),
                "inputs": dict(inputs),
                "config": _canonical(config),
                "timings_s": {k: float(v) for k, v in (timings or {}).items()},
                "metrics": _canonical(dict(metrics or {})),
                "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                **({"extra": _canonical(dict(extra))} if extra else {}),
            }
            tmp_manifest = tmp / (MANIFEST + ".part")
            tmp_manifest.write_text(json.dumps(manifest, indent=1, sort_keys=True, allow_nan=True))
            os.replace(tmp_manifest, tmp / MANIFEST)
            try:
                os.rename(tmp, final)
            except OSError:
                if not (final / MANIFEST).is_file():
                    # a stale, incomplete folder at the final place (cannot come from put); replace it
                    shutil.rmtree(final, ignore_errors=True)
                    os.rename(tmp, final)
                else:
                    shutil.rmtree(tmp, ignore_errors=True)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return self.ref(stage, key)

    def save(
        self,
        stage: str,
        key: str,
        value: Any,
        *,
        inputs: Mapping[str, str],
        config: Any,
        timings: Mapping[str, float] | None = None,
        metrics: Mapping[str, Any] | None = None,
        extra: Mapping[str, Any] | None = None,
    ) -> ArtifactRef:
        """Store a stage value (``service.io.save_value`` under ``value/``)."""
        return self.put(
            stage,
            key,
            lambda folder: save_value(value, folder / VALUE_DIR),
            inputs=inputs,
            config=config,
            timings=timings,
            metrics=metrics,
            extra=extra,
        )

    def clean_tmp(self, older_than_s: float = 3600.0) -> int:
        """Remove temporary folders left by crashed writers; returns how many were removed."""
        n = 0
        now = time.time()
        if not self.root.is_dir():
            return 0
        for stage_dir in self.root.iterdir():
            if not stage_dir.is_dir():
                continue
            for tmp in stage_dir.glob(".tmp-*"):
                if now - tmp.stat().st_mtime > older_than_s:
                    shutil.rmtree(tmp, ignore_errors=True)
                    n += 1
        return n
