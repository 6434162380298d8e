"""Safe unpacking of an uploaded session (zip, tar, tar.gz/tgz or a plain folder) into a staging folder.

Nothing is trusted: every member name is normalised and checked (relative, no ``..``, no drive letters,
no NUL), only regular files and folders are accepted (tar symlinks, hard links, devices and FIFOs, and zip
entries whose Unix mode is a link or special file, are refused), and each file is written member by member
with ``O_EXCL | O_NOFOLLOW`` while its bytes are counted. Limits (``service.settings.Limits``) apply both to
the sizes the archive declares and to the bytes actually produced, so a lying header cannot smuggle a bomb:

* archive size <= ``max_upload_bytes``; members <= ``max_entries``;
* sum of unpacked sizes <= ``max_unpacked_bytes``;
* unpacked / archive size <= ``max_compression_ratio`` (checked once more than 1 MiB is unpacked, so tiny
  archives whose size is dominated by headers are not refused).

Tar archives are read as a stream (``r|``) through a counting decompressor, so a member whose header
declares an absurd size is refused before any of its data is read.

macOS archive litter (``__MACOSX/``, ``.DS_Store``, ``._*`` files) is skipped, not unpacked.
"""

from __future__ import annotations

import gzip
import io
import os
import stat
import tarfile
import zipfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from service.errors import InvalidSession
from service.settings import Limits

RATIO_FLOOR_BYTES = 1 << 20  # the compression-ratio limit applies once this much is unpacked
_CHUNK = 1 << 20
SIDECAR = ".vysics-ingest.json"  # written by ingest next to session.json; never taken from an upload


def _is_litter(parts: tuple[str, ...]) -> bool:
    return parts[0] == "__MACOSX" or parts[-1] == ".DS_Store" or parts[-1].startswith("._") or parts[-1] == SIDECAR


def normalise_member(name: str) -> tuple[str, ...]:
    """Member name -> tuple of path parts, or InvalidSession when the name is not a safe relative path."""
    if "\x00" in name:
        raise InvalidSession(repr(name), "member name contains a NUL character")
    n = name.replace("\\", "/")
    if n.startswith("/") or (len(n) >= 2 and n[1] == ":"):
        raise InvalidSession(name, "absolute path in archive; member names must be relative")
    parts = tuple(p for p in n.split("/") if p not in ("", "."))
    if any(p == ".." for p in parts):
        raise InvalidSession(name, "path contains '..'; member names must stay inside the archive")
    return parts


@dataclass
class _Budget:
    """Counts entries and bytes against the limits."""

    limits: Limits
    archive_name: str
    packed_bytes: int
    entries: int = 0
    declared: int = 0
    written: int = 0

    def entry(self, name: str) -> None:
        self.entries += 1
        if self.entries > self.limits.max_entries:
            raise InvalidSession(self.archive_name, f"more than {self.limits.max_entries} members (limit max_entries)")

    def declare(self, name: str, size: int) -> None:
        if size < 0:
            raise InvalidSession(name, "negative member size in archive header")
        self.declared += size
        self._check(self.declared, name, "declared")

    def wrote(self, name: str, n: int) -> None:
        self.written += n
        self._check(self.written, name, "unpacked")

    def _check(self, total: int, name: str, what: str) -> None:
        lim = self.limits
        if total > lim.max_unpacked_bytes:
            raise InvalidSession(
                name, f"{what} size exceeds {lim.max_unpacked_bytes} bytes in total (limit max_unpacked_bytes)"
            )
        if total > RATIO_FLOOR_BYTES and total > lim.max_compression_ratio * max(self.packed_bytes, 1):
            raise InvalidSession(
                self.archive_name,
                f"compression ratio over {lim.max_compression_ratio:g} ({what} {total} bytes from a "
                f"{self.packed_bytes}-byte archive; limit max_compression_ratio)",
            )


class _Writer:
    """Creates folders and files under ``dest`` with the budget's checks, never following links."""

    def __init__(self, dest: Path, budget: _Budget):
        self.dest = dest
        self.budget = budget
        self.files: set[tuple[str, ...]] = set()
        self.dirs: set[tuple[str, ...]] = set()

    def _mkdirs(self, parts: tuple[str, ...], name: str) -> None:
        for i in range(1, len(parts) + 1):
            sub = parts[:i]
            if sub in self.files:
                raise InvalidSession(name, f"'{'/'.join(sub)}' is both a file and a folder in the archive")
            if sub not in self.dirs:
                p = self.dest.joinpath(*sub)
                try:
                    p.mkdir(mode=0o755)
                except FileExistsError:
                    if p.is_symlink() or not p.is_dir():
                        raise InvalidSession(name, "member path collides with another member") from None
                self.dirs.add(sub)

    def mkdir(self, parts: tuple[str, ...], name: str) -> None:
        if parts:
            self._mkdirs(parts, name)

    def write(self, parts: tuple[str, ...], name: str, src: BinaryIO, declared: int | None) -> None:
        if not parts:
            raise InvalidSession(name, "member has an empty name")
        if parts in self.files:
            raise InvalidSession(name, "duplicate member in archive")
        if parts in self.dirs:
            raise InvalidSession(name, f"'{'/'.join(parts)}' is both a file and a folder in the archive")
        self._mkdirs(parts[:-1], name)
        target = self.dest.joinpath(*parts)
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_BINARY", 0)
        try:
            fd = os.open(target, flags, 0o644)
        except FileExistsError:
            raise InvalidSession(name, "duplicate member in archive") from None
        self.files.add(parts)
        n = 0
        with os.fdopen(fd, "wb") as out:
            while True:
                chunk = src.read(_CHUNK)
                if not chunk:
                    break
                n += len(chunk)
                if declared is not None and n > declared:
                    raise InvalidSession(name, "member holds more data than its header declares (corrupt archive)")
                self.budget.wrote(name, len(chunk))
                out.write(chunk)
        if declared is not None and n != declared:
            raise InvalidSession(name, f"member is truncated ({n} of {declared} bytes; corrupt or truncated archive)")


class _CountingReader(io.RawIOBase):
    """Wraps a decompressed stream and refuses to produce more than ``cap`` bytes."""

    def __init__(self, raw: BinaryIO, cap: int, on_exceed: Callable[[], None]):
        self.raw = raw
        self.cap = cap
        self.count = 0
        self.on_exceed = on_exceed

    def readable(self) -> bool:
        return True

    def readinto(self, b) -> int:  # type: ignore[override]
        data = self.raw.read(len(b))
        n = len(data)
        self.count += n
        if self.count > self.cap:
            self.on_exceed()
        b[:n] = data
        return n


def detect_kind(source: Path) -> str:
    """'zip' | 'tar' | 'tgz' from the file's first bytes (the extension is not trusted)."""
    with open(source, "rb") as f:
        head = f.read(512)
    if head[:4] in (b"PK\x03\x04", b"PK\x05\x06"):
        return "zip"
    if head[:2] == b"\x1f\x8b":
        return "tgz"
    if len(head) >= 262 and head[257:262] == b"ustar":
        return "tar"
    if len(head) == 512:
        try:
            tarfile.TarInfo.frombuf(head, "utf-8", "surrogateescape")
            return "tar"
        except tarfile.TarError:
            pass
    raise InvalidSession(source.name, "not a zip, tar, tar.gz or tgz archive (unrecognised file header)")


def _unpack_zip(source: Path, writer: _Writer, budget: _Budget) -> None:
    name0 = source.name
    try:
        zf = zipfile.ZipFile(source)
    except (zipfile.BadZipFile, OSError, EOFError) as e:
        raise InvalidSession(name0, f"corrupt or truncated zip archive ({e})") from None
    with zf:
        infos = zf.infolist()
        if len(infos) > budget.limits.max_entries:
            raise InvalidSession(name0, f"more than {budget.limits.max_entries} members (limit max_entries)")
        plan: list[tuple[zipfile.ZipInfo, tuple[str, ...]]] = []
        for info in infos:
            parts = normalise_member(info.filename)
            if not parts or _is_litter(parts):
                continue
            budget.entry(info.filename)
            mode = info.external_attr >> 16
            ftype = stat.S_IFMT(mode)
            if ftype == stat.S_IFLNK:
                raise InvalidSession(info.filename, "symbolic link in archive; only regular files are accepted")
            if ftype not in (0, stat.S_IFREG, stat.S_IFDIR):
                raise InvalidSession(info.filename, "special file in archive; only regular files are accepted")
            if info.flag_bits & 0x1:
                raise InvalidSession(info.filename, "encrypted member; archives must not be encrypted")
            if not info.is_dir():
                budget.declare(info.filename, info.file_size)
            plan.append((info, parts))
        # the declared totals passed: now write, counting the real bytes
        for info, parts in plan:
            if info.is_dir():
                writer.mkdir(parts, info.filename)
                continue
            try:
                with zf.open(info) as src:
                    writer.write(parts, info.filename, src, info.file_size)
            except InvalidSession:
                raise
            except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError, ValueError, NotImplementedError) as e:
                raise InvalidSession(info.filename, f"corrupt or truncated zip member ({e})") from None
            except Exception as e:  # zlib.error and friends
                raise InvalidSession(info.filename, f"corrupt zip member ({type(e).__name__}: {e})") from None


def _unpack_tar(source: Path, kind: str, writer: _Writer, budget: _Budget) -> None:
    name0 = source.name
    lim = budget.limits
    # raw stream cap: content limit plus header/padding overhead of every allowed entry
    cap = min(
        lim.max_unpacked_bytes + 1536 * (lim.max_entries + 4),
        int(lim.max_compression_ratio * max(budget.packed_bytes, 1)) + RATIO_FLOOR_BYTES + 1536 * (lim.max_entries + 4),
    )

    def exceed() -> None:
        raise InvalidSession(
            name0,
            f"archive expands beyond the limits (compression ratio over {lim.max_compression_ratio:g} "
            f"or more than {lim.max_unpacked_bytes} bytes; limits max_compression_ratio / max_unpacked_bytes)",
        )

    with open(source, "rb") as raw:
        stream: BinaryIO = gzip.GzipFile(fileobj=raw, mode="rb") if kind == "tgz" else raw  # type: ignore[assignment]
        counted = io.BufferedReader(_CountingReader(stream, cap, exceed), buffer_size=_CHUNK)
        try:
            with tarfile.open(fileobj=counted, mode="r|") as tf:
                seen_any = False
                for m in tf:
                    seen_any = True
                    parts = normalise_member(m.name)
                    if not parts or _is_litter(parts):
                        continue
                    budget.entry(m.name)
                    if m.issym() or m.islnk():
                        kind_s = "symbolic link" if m.issym() else "hard link"
                        raise InvalidSession(m.name, f"{kind_s} in archive; only regular files are accepted")
                    if m.isdir():
                        writer.mkdir(parts, m.name)
                        continue
                    if not m.isreg():
                        raise InvalidSession(m.name, "device, FIFO or other special file in archive; only regular files are accepted")
                    budget.declare(m.name, m.size)
                    src = tf.extractfile(m)
                    assert src is not None
                    writer.write(parts, m.name, src, m.size)
                if not seen_any:
                    raise InvalidSession(name0, "empty tar archive")
        except InvalidSession:
            raise
        except (tarfile.TarError, EOFError, OSError, gzip.BadGzipFile, ValueError) as e:
            raise InvalidSession(name0, f"corrupt or truncated tar archive ({type(e).__name__}: {e})") from None
        except Exception as e:  # zlib.error
            raise InvalidSession(name0, f"corrupt or truncated archive ({type(e).__name__}: {e})") from None


def iter_folder(source: Path) -> Iterator[tuple[tuple[str, ...], Path, bool]]:
    """(parts, path, is_dir) for every entry under ``source``, sorted, without following links."""
    for dirpath, dirnames, filenames in os.walk(source, followlinks=False):
        dirnames.sort()
        rel = Path(dirpath).relative_to(source)
        base = tuple(p for p in rel.parts if p != ".")
        for d in list(dirnames):
            yield base + (d,), Path(dirpath) / d, True
        for f in sorted(filenames):
            yield base + (f,), Path(dirpath) / f, False


def _copy_folder(source: Path, writer: _Writer, budget: _Budget) -> None:
    for parts, path, is_dir in iter_folder(source):
        if _is_litter(parts):
            continue
        name = "/".join(parts)
        budget.entry(name)
        st = os.lstat(path)
        if stat.S_ISLNK(st.st_mode):
            raise InvalidSession(name, "symbolic link in session folder; only regular files are accepted")
        if is_dir:
            writer.mkdir(parts, name)
            continue
        if not stat.S_ISREG(st.st_mode):
            raise InvalidSession(name, "special file in session folder; only regular files are accepted")
        budget.declare(name, st.st_size)
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
        with os.fdopen(fd, "rb") as src:
            writer.write(parts, name, src, None)


def check_upload(source: Path, limits: Limits) -> int:
    """Size checks of an archive file before anything reads it; returns its size."""
    if not source.is_file():
        raise InvalidSession(source.name, "upload not found or not a regular file")
    size = source.stat().st_size
    if size > limits.max_upload_bytes:
        raise InvalidSession(
            source.name, f"archive is {size} bytes, over the {limits.max_upload_bytes}-byte limit (max_upload_bytes)"
        )
    if size == 0:
        raise InvalidSession(source.name, "empty file, expected a zip, tar, tar.gz or tgz archive")
    return size


def unpack(source: Path, dest: Path, limits: Limits) -> None:
    """Unpack ``source`` (archive or folder) into the existing empty folder ``dest``.

    Raises InvalidSession on any breach; the caller cleans ``dest`` up.
    """
    if source.is_dir():
        budget = _Budget(limits, source.name, packed_bytes=1 << 62)  # no compression in a folder
        _copy_folder(source, _Writer(dest, budget), budget)
        return
    size = check_upload(source, limits)
    kind = detect_kind(source)
    budget = _Budget(limits, source.name, packed_bytes=size)
    writer = _Writer(dest, budget)
    if kind == "zip":
        _unpack_zip(source, writer, budget)
    else:
        _unpack_tar(source, kind, writer, budget)


def find_root(dest: Path, archive_name: str) -> Path:
    """The folder holding session.json: ``dest`` itself or its only top-level folder."""
    if (dest / "session.json").is_file():
        return dest
    tops = sorted(p.name for p in dest.iterdir())
    dirs = [t for t in tops if (dest / t).is_dir()]
    if len(tops) == 1 and len(dirs) == 1:
        root = dest / dirs[0]
        if (root / "session.json").is_file():
            return root
        raise InvalidSession("session.json", f"missing (not found at the root nor in the top-level folder '{dirs[0]}/')")
    if len(tops) > 1 and any((dest / d / "session.json").is_file() for d in dirs):
        raise InvalidSession(
            archive_name,
            "files must sit at the archive root or inside exactly one top-level folder; found "
            + ", ".join(f"'{t}'" for t in tops),
        )
    if not tops:
        raise InvalidSession(archive_name, "archive holds no files")
    raise InvalidSession("session.json", "missing at the archive root (required)")
