"""Stored sessions: ``<data_dir>/sessions/<sha256>/`` holds a validated, unpacked upload.

``store_upload`` is the one path by which bytes become a stored session (API upload and command line):
hash -> if already stored, reuse -> else ``service.session.ingest`` into a staging folder under
``uploads/`` (raises ``InvalidSession`` and leaves nothing behind on bad input) -> rename into
``sessions/<sha256>/``. The ingest time and a summary are recorded as the ``ingest`` artifact of the store.

Plain Python (no prefect, no torch): the API imports it.
"""

from __future__ import annotations

import os
import re
import shutil
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

from service.store import ArtifactRef, ArtifactStore

SHA_RE = re.compile(r"^[0-9a-f]{64}$")


@dataclass(frozen=True)
class StoredSession:
    sha256: str
    root: Path  # folder holding session.json
    name: str
    frames: int
    ingest_ref: ArtifactRef
    ingest_seconds: float
    reused: bool  # True when these bytes were stored before


def session_dir(data_dir: Path, sha: str) -> Path:
    return Path(data_dir) / "sessions" / sha


def find_root(folder: Path) -> Path | None:
    """The folder holding ``session.json`` (``folder`` itself or its one top-level folder, the rule of
    ``service.session.archive.find_root``), or None when ``folder`` holds no stored session."""
    from service.errors import InvalidSession
    from service.session.archive import find_root as _find_root

    folder = Path(folder)
    if not folder.is_dir():
        return None
    try:
        return _find_root(folder, folder.name)
    except InvalidSession:
        return None


def is_sha(s: str) -> bool:
    return bool(SHA_RE.match(s))


def ingest_key(store: ArtifactStore, sha: str) -> str:
    return store.key("ingest", {"upload": sha}, {})


def _record_ingest(store: ArtifactStore, sha: str, root: Path, session, seconds: float) -> ArtifactRef:
    key = ingest_key(store, sha)
    ref = store.get("ingest", key)
    if ref is not None:
        return ref
    summary = {"sha256": sha, "name": session.name, "frames": int(session.n_frames), "width": int(session.width),
               "height": int(session.height), "table_height": float(session.table_height),
               "table_height_detected": bool(session.table_height_detected),
               "has_ground_truth": bool(session.has_ground_truth)}
    return store.save("ingest", key, {"root": str(root), **summary}, inputs={"upload": sha}, config={},
                      timings={"ingest": seconds}, metrics=summary)


def load_stored(data_dir: Path, sha: str, store: ArtifactStore | None = None):
    """``(Session, StoredSession)`` of an already stored session (``KeyError`` if there is none)."""
    from service.session import load_session

    data_dir = Path(data_dir)
    root = find_root(session_dir(data_dir, sha))
    if root is None:
        raise KeyError(sha)
    store = store or ArtifactStore(data_dir / "artifacts")
    t0 = time.perf_counter()
    session = load_session(root, sha)
    ref = store.get("ingest", ingest_key(store, sha))
    seconds = time.perf_counter() - t0
    if ref is None:
        ref = _record_ingest(store, sha, root, session, seconds)
    else:
        seconds = float(store.manifest(ref).get("timings_s", {}).get("ingest", seconds))
    return session, StoredSession(sha, root, session.name, session.n_frames, ref, seconds, True)


def store_upload(source: Path, data_dir: Path, *, sha: str | None = None, limits=None, progress=None,
                 store: ArtifactStore | None = None):
    """Validate and store ``source`` (archive file or session folder). Returns ``(Session, StoredSession)``.

    Raises ``service.errors.InvalidSession`` on bad input; then nothing new is left under ``data_dir``.
    ``sha`` may be given when the caller already hashed the bytes (streamed upload)."""
    from service.session import ingest, sha256_of

    source, data_dir = Path(source), Path(data_dir)
    store = store or ArtifactStore(data_dir / "artifacts")
    sha = sha or sha256_of(source)
    final = session_dir(data_dir, sha)
    if find_root(final) is not None:
        return load_stored(data_dir, sha, store)
    uploads = data_dir / "uploads"
    uploads.mkdir(parents=True, exist_ok=True)
    staging = uploads / f"staging-{uuid.uuid4().hex}"
    t0 = time.perf_counter()
    try:
        session = ingest(source, staging, limits=limits, progress=progress)
        seconds = time.perf_counter() - t0
        final.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.rename(staging, final)
        except OSError:
            if find_root(final) is None:  # a broken leftover; replace it
                shutil.rmtree(final, ignore_errors=True)
                os.rename(staging, final)
            # else: the same bytes were stored concurrently; keep theirs
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    root = find_root(final)
    from service.session import load_session

    if root != session.root:
        session = load_session(root, sha)
    ref = _record_ingest(store, sha, root, session, seconds)
    return session, StoredSession(sha, root, session.name, session.n_frames, ref, seconds, False)
