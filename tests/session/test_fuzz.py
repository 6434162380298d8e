"""Corrupted uploads (random byte flips, truncations, insertions) only ever raise InvalidSession,
and a refused upload leaves nothing behind. Also: a Session survives the stage-value round trip."""

from __future__ import annotations

import random
import shutil

import numpy as np

from service.errors import InvalidSession
from service.io import load_value, save_value
from service.session import Session, ingest
from tests.session.conftest import Spec, pack, write_session


def _mutate(b: bytearray, rng: random.Random) -> bytearray:
    for _ in range(rng.randint(1, 4)):
        op = rng.random()
        if op < 0.6 and b:
            b[rng.randrange(len(b))] = rng.randrange(256)
        elif op < 0.8:
            b = b[: rng.randrange(len(b) + 1)]
        else:
            i = rng.randrange(len(b) + 1)
            b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 8)))
    return b


def test_corrupted_uploads_raise_only_invalid_session(tmp_path):
    src = write_session(tmp_path / "src", Spec(rgb_ext=".png"))
    arcs = {k: pack(src, tmp_path / f"a.{k}", k).read_bytes() for k in ("zip", "tar", "tgz")}
    rng = random.Random(1)
    outcomes = {"ok": 0, "invalid": 0}
    for it in range(48):
        kind = ("zip", "tar", "tgz", "folder")[it % 4]
        if kind == "folder":
            source = tmp_path / f"w{it}"
            shutil.copytree(src, source)
            f = rng.choice(sorted(p for p in source.rglob("*") if p.is_file()))
            f.write_bytes(bytes(_mutate(bytearray(f.read_bytes()), rng)))
        else:
            source = tmp_path / f"w{it}.{kind}"
            source.write_bytes(bytes(_mutate(bytearray(arcs[kind]), rng)))
        dest = tmp_path / f"out{it}"
        try:
            ingest(source, dest)
            outcomes["ok"] += 1
        except InvalidSession as e:
            assert e.file and e.rule
            assert not dest.exists()
            outcomes["invalid"] += 1
    assert outcomes["invalid"] >= 30


def test_session_round_trips_as_a_stage_value(tmp_path):
    s = ingest(write_session(tmp_path / "src"), tmp_path / "d")
    save_value(s, tmp_path / "v")
    r = load_value(Session, tmp_path / "v")
    assert r.root == s.root and r.rgb_files == s.rgb_files and r.friction == s.friction
    for f in ("frame_times", "K", "X_WC", "robot_t", "robot_p_WE", "p_WE", "cmd_WE"):
        np.testing.assert_array_equal(getattr(r, f), getattr(s, f))
    assert (r.table_height, r.table_height_detected, r.mass, r.name) == (s.table_height, s.table_height_detected, s.mass, s.name)
