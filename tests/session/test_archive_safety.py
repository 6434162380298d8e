"""Archive safety beyond the corpus: member-name normalisation (exhaustive over small names), headers
that lie, Windows-style names, entry and size limits."""

from __future__ import annotations

import gzip
import io
import itertools
import tarfile
import zipfile
from pathlib import PurePosixPath

import pytest

from service.errors import InvalidSession
from service.session import ingest
from service.session.archive import normalise_member
from service.settings import Limits
from tests.session.conftest import pack, tree, write_session

_PARTS = ["..", ".", "", "a", "b.png", "C:", "x\\..", "\\", "..\\a"]


def test_normalised_names_stay_inside():
    """Every name of up to 4 parts from a nasty alphabet either is refused or stays under the root."""
    n_ok = n_refused = 0
    for k in range(1, 5):
        for combo in itertools.product(_PARTS, repeat=k):
            name = "/".join(combo)
            try:
                parts = normalise_member(name)
            except InvalidSession as e:
                assert e.rule
                n_refused += 1
                continue
            n_ok += 1
            assert all(p not in ("", ".", "..") and "/" not in p and "\\" not in p for p in parts)
            target = PurePosixPath("/dest").joinpath(*parts)
            assert ".." not in target.parts and target.parts[:2] == ("/", "dest")
    assert n_ok > 100 and n_refused > 100


@pytest.mark.parametrize("name", ["C:/x/evil.txt", "c:evil.txt", "\\\\server\\share\\x", "/abs"])
def test_windows_and_absolute_names_refused(name):
    with pytest.raises(InvalidSession, match="absolute path"):
        normalise_member(name)


def test_backslash_names_are_folders(tmp_path):
    src = write_session(tmp_path / "src")
    arc = pack(src, tmp_path / "a.zip", "zip")
    arc.write_bytes(arc.read_bytes().replace(b"rgb/000000.jpg", b"rgb\\000000.jpg"))
    s = ingest(arc, tmp_path / "d")
    assert (tmp_path / "d" / "rgb" / "000000.jpg").is_file() and s.n_frames == 4


def test_tar_header_declaring_huge_size_refused_before_reading(tmp_path):
    """A member header claims 50 MiB but the stream ends: refused on the declared size, before any data."""
    ti = tarfile.TarInfo("rgb/000000.jpg")
    ti.size = 50 << 20
    arc = tmp_path / "a.tgz"
    arc.write_bytes(gzip.compress(ti.tobuf(format=tarfile.USTAR_FORMAT) + b"\0" * 512))
    with pytest.raises(InvalidSession) as ei:
        ingest(arc, tmp_path / "d", limits=Limits(max_unpacked_bytes=10 << 20))
    assert ei.value.file == "rgb/000000.jpg" and "max_unpacked_bytes" in ei.value.rule
    assert not (tmp_path / "d").exists()


def test_zip_declared_sizes_over_limit_refused_before_writing(tmp_path):
    src = write_session(tmp_path / "src")
    arc = pack(src, tmp_path / "a.zip", "zip")
    with zipfile.ZipFile(arc, "a", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("big.bin", b"x" * 200_000)
    with pytest.raises(InvalidSession, match="max_unpacked_bytes"):
        ingest(arc, tmp_path / "d", limits=Limits(max_unpacked_bytes=150_000))
    assert not (tmp_path / "d").exists()


def test_entry_limit_stops_a_flood_of_entries(tmp_path):
    """Thousands of folder entries inflate from very little: the entry limit stops the stream."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w") as tf:
        for i in range(600):
            ti = tarfile.TarInfo(f"d{i}")
            ti.type = tarfile.DIRTYPE
            tf.addfile(ti)
    arc = tmp_path / "a.tgz"
    arc.write_bytes(gzip.compress(buf.getvalue(), 9))
    with pytest.raises(InvalidSession, match="max_entries"):
        ingest(arc, tmp_path / "d", limits=Limits(max_entries=50))
    assert tree(tmp_path / "d") == []


def test_gzip_stream_cap(tmp_path):
    """A huge PAX header (read into memory by tarfile, not a member) is stopped by the stream cap."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w", format=tarfile.PAX_FORMAT) as tf:
        ti = tarfile.TarInfo("session.json")
        ti.pax_headers = {"comment": "x" * (6 << 20)}
        tf.addfile(ti, io.BytesIO(b""))
    arc = tmp_path / "a.tgz"
    arc.write_bytes(gzip.compress(buf.getvalue(), 9))
    with pytest.raises(InvalidSession, match="expands beyond the limits"):
        ingest(arc, tmp_path / "d", limits=Limits(max_unpacked_bytes=1 << 20, max_entries=10))
    assert not (tmp_path / "d").exists()


def test_tar_extension_is_irrelevant(tmp_path):
    src = write_session(tmp_path / "src")
    arc = pack(src, tmp_path / "upload.bin", "tar")
    assert ingest(arc, tmp_path / "d").n_frames == 4


def test_empty_file_refused(tmp_path):
    p = tmp_path / "a.zip"
    p.write_bytes(b"")
    with pytest.raises(InvalidSession, match="empty file"):
        ingest(p, tmp_path / "d")


def test_zip_encrypted_member_refused(tmp_path):
    src = write_session(tmp_path / "src")
    arc = pack(src, tmp_path / "a.zip", "zip")
    data = bytearray(arc.read_bytes())
    i = 0
    while (i := data.find(b"PK\x01\x02", i)) >= 0:  # central directory entry of robot.csv: set bit 0
        nlen = int.from_bytes(data[i + 28 : i + 30], "little")
        if bytes(data[i + 46 : i + 46 + nlen]) == b"robot.csv":
            data[i + 8] |= 0x1
        i += 4
    arc.write_bytes(bytes(data))
    with pytest.raises(InvalidSession) as ei:
        ingest(arc, tmp_path / "d")
    assert ei.value.file == "robot.csv" and "encrypted" in ei.value.rule


def test_dot_slash_member_names(tmp_path):
    """`tar czf s.tgz -C folder .` writes ./session.json, ./rgb/...: that is the archive root."""
    src = write_session(tmp_path / "src")
    arc = tmp_path / "a.tgz"
    with tarfile.open(arc, "w:gz") as tf:
        tf.add(src, ".")
    s = ingest(arc, tmp_path / "d")
    assert s.root == (tmp_path / "d").resolve() and s.n_frames == 4
