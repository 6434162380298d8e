"""A corpus of bad uploads made here: each must raise InvalidSession naming the file and the rule,
and leave the destination absent and nothing else touched."""

from __future__ import annotations

import json
import os
import stat
import tarfile
import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from service.errors import InvalidSession
from service.session import ingest
from service.settings import Limits
from tests.session.conftest import DELETE, Spec, add_tar_member, pack, tree, write_session


def _ok(tmp: Path, spec: Spec | None = None) -> Path:
    return write_session(tmp / "src", spec)


def _json(tmp, **patch):
    return _ok(tmp, Spec(meta=patch))


# ---------------------------------------------------------------- container attacks


def traversal_tar(tmp):
    src = _ok(tmp)
    arc = pack(src, tmp / "a.tar", "tar")
    with tarfile.open(arc, "a") as tf:
        add_tar_member(tf, "../evil.txt", b"pwned")
    return arc


def traversal_zip(tmp):
    src = _ok(tmp)
    arc = pack(src, tmp / "a.zip", "zip")
    with zipfile.ZipFile(arc, "a") as zf:
        zf.writestr("rgb/../../evil.txt", b"pwned")
    return arc


def absolute_zip(tmp):
    src = _ok(tmp)
    arc = pack(src, tmp / "a.zip", "zip")
    with zipfile.ZipFile(arc, "a") as zf:
        zi = zipfile.ZipInfo("placeholder")
        zi.filename = "/tmp/evil.txt"  # ZipInfo() strips leading slashes; set it raw
        zf.writestr(zi, b"pwned")
    return arc


def absolute_tar(tmp):
    src = _ok(tmp)
    arc = pack(src, tmp / "a.tar", "tar")
    with tarfile.open(arc, "a") as tf:
        add_tar_member(tf, "/tmp/evil.txt", b"pwned")
    return arc


def symlink_tar(tmp):
    src = _ok(tmp)
    arc = pack(src, tmp / "a.tgz", "tgz")
    raw = tmp / "b.tar"
    with tarfile.open(arc) as tin, tarfile.open(raw, "w") as tout:
        for m in tin.getmembers():
            tout.addfile(m, tin.extractfile(m))
        add_tar_member(tout, "rgb/link.jpg", type=tarfile.SYMTYPE, linkname="/etc/passwd")
    return raw


def hardlink_tar(tmp):
    src = _ok(tmp)
    arc = pack(src, tmp / "a.tar", "tar")
    with tarfile.open(arc, "a") as tf:
        add_tar_member(tf, "notes.txt", type=tarfile.LNKTYPE, linkname="/etc/passwd")
    return arc


def device_tar(tmp):
    src = _ok(tmp)
    arc = pack(src, tmp / "a.tar", "tar")
    with tarfile.open(arc, "a") as tf:
        add_tar_member(tf, "dev", type=tarfile.CHRTYPE, devmajor=1, devminor=3)
    return arc


def symlink_zip(tmp):
    src = _ok(tmp)
    arc = pack(src, tmp / "a.zip", "zip")
    with zipfile.ZipFile(arc, "a") as zf:
        zi = zipfile.ZipInfo("rgb/link.jpg")
        zi.create_system = 3
        zi.external_attr = (stat.S_IFLNK | 0o777) << 16
        zf.writestr(zi, "/etc/passwd")
    return arc


def symlink_folder(tmp):
    src = _ok(tmp)
    os.symlink("/etc/passwd", src / "notes.txt")
    return src


def zip_bomb(tmp):
    src = _ok(tmp)
    arc = pack(src, tmp / "a.zip", "zip")
    with zipfile.ZipFile(arc, "a", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("padding.bin", b"\0" * (8 << 20))  # 8 MiB of zeros -> ~8 KiB
    return arc


def tgz_bomb(tmp):
    src = _ok(tmp)
    arc = tmp / "a.tgz"
    with tarfile.open(arc, "w:gz") as tf:
        for p in sorted(src.rglob("*")):
            if p.is_file():
                tf.add(p, p.relative_to(src).as_posix())
        add_tar_member(tf, "padding.bin", b"\0" * (8 << 20))
    return arc


def zip_lying_header(tmp):
    """A member whose declared size is tiny but whose stream inflates to much more."""
    src = _ok(tmp)
    arc = pack(src, tmp / "a.zip", "zip")
    with zipfile.ZipFile(arc, "a", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("padding.bin", b"\0" * (4 << 20))
    data = bytearray(arc.read_bytes())
    # patch the uncompressed size (local header and central directory) of padding.bin to 10 bytes
    name = b"padding.bin"
    for sig, off_size in ((b"PK\x03\x04", 22), (b"PK\x01\x02", 24)):
        i = 0
        while (i := data.find(sig, i)) >= 0:
            nlen_off = 26 if sig == b"PK\x03\x04" else 28
            nlen = int.from_bytes(data[i + nlen_off : i + nlen_off + 2], "little")
            hdr = 30 if sig == b"PK\x03\x04" else 46
            if bytes(data[i + hdr : i + hdr + nlen]) == name:
                data[i + off_size : i + off_size + 4] = (10).to_bytes(4, "little")
            i += 4
    arc.write_bytes(bytes(data))
    return arc


def truncated_zip(tmp):
    arc = pack(_ok(tmp), tmp / "a.zip", "zip")
    arc.write_bytes(arc.read_bytes()[: arc.stat().st_size // 2])
    return arc


def truncated_tgz(tmp):
    arc = pack(_ok(tmp), tmp / "a.tgz", "tgz")
    arc.write_bytes(arc.read_bytes()[: arc.stat().st_size // 2])
    return arc


def truncated_tar(tmp):
    arc = pack(_ok(tmp), tmp / "a.tar", "tar")
    arc.write_bytes(arc.read_bytes()[:3000])
    return arc


def corrupt_zip_member(tmp):
    src = _ok(tmp)
    arc = tmp / "a.zip"
    with zipfile.ZipFile(arc, "w", zipfile.ZIP_DEFLATED) as zf:
        for p in sorted(src.rglob("*")):
            if p.is_file():
                zf.write(p, p.relative_to(src).as_posix())
    data = bytearray(arc.read_bytes())
    i = data.find(b"robot.csv") + len(b"robot.csv") + 5
    for k in range(i, i + 20):
        data[k] ^= 0xFF
    arc.write_bytes(bytes(data))
    return arc


def not_an_archive(tmp):
    p = tmp / "a.zip"
    p.write_bytes(b"hello, this is not an archive" * 20)
    return p


def two_top_folders(tmp):
    src = _ok(tmp)
    arc = tmp / "a.zip"
    with zipfile.ZipFile(arc, "w") as zf:
        for top in ("take1", "take2"):
            for p in sorted(src.rglob("*")):
                if p.is_file():
                    zf.write(p, f"{top}/{p.relative_to(src).as_posix()}")
    return arc


def duplicate_member(tmp):
    src = _ok(tmp)
    arc = pack(src, tmp / "a.tar", "tar")
    with tarfile.open(arc, "a") as tf:
        add_tar_member(tf, "robot.csv", b"t,ee_x\n")
    return arc


# ---------------------------------------------------------------- content


def missing_session_json(tmp):
    src = _ok(tmp)
    (src / "session.json").unlink()
    return pack(src, tmp / "a.zip", "zip", top="s")


def missing_robot_csv(tmp):
    src = _ok(tmp)
    (src / "robot.csv").unlink()
    return src


def missing_depth_frame(tmp):
    src = _ok(tmp)
    (src / "depth" / "000002.png").unlink()
    return pack(src, tmp / "a.tgz", "tgz")


def extra_depth_frame(tmp):
    src = _ok(tmp)
    (src / "rgb" / "000003.jpg").unlink()
    return src


def missing_masks_folder(tmp):
    src = _ok(tmp)
    for p in (src / "masks").iterdir():
        p.unlink()
    (src / "masks").rmdir()
    return src


def depth_8bit(tmp):
    src = _ok(tmp)
    cv2.imwrite(str(src / "depth" / "000001.png"), np.full((24, 32), 100, np.uint8))
    return pack(src, tmp / "a.zip", "zip")


def depth_rgb(tmp):
    src = _ok(tmp)
    cv2.imwrite(str(src / "depth" / "000001.png"), np.full((24, 32, 3), 100, np.uint16))
    return src


def depth_jpeg(tmp):
    src = _ok(tmp)
    (src / "depth" / "000001.png").unlink()
    cv2.imwrite(str(src / "depth" / "000001.jpg"), np.full((24, 32), 100, np.uint8))
    return src


def mask_16bit(tmp):
    src = _ok(tmp)
    cv2.imwrite(str(src / "masks" / "000000.png"), np.zeros((24, 32), np.uint16))
    return src


def rgb_grayscale(tmp):
    src = _ok(tmp)
    cv2.imwrite(str(src / "rgb" / "000002.jpg"), np.zeros((24, 32), np.uint8))
    return src


def rgb_wrong_size(tmp):
    src = _ok(tmp)
    cv2.imwrite(str(src / "rgb" / "000002.jpg"), np.zeros((30, 40, 3), np.uint8))
    return src


def mask_wrong_size(tmp):
    src = _ok(tmp)
    cv2.imwrite(str(src / "masks" / "000003.png"), np.zeros((30, 40), np.uint8))
    return src


def truncated_png(tmp):
    src = _ok(tmp)
    p = src / "depth" / "000002.png"
    p.write_bytes(p.read_bytes()[:-20])
    return src


def bitflip_png(tmp):
    src = _ok(tmp)
    p = src / "depth" / "000002.png"
    b = bytearray(p.read_bytes())
    b[60] ^= 0x55
    p.write_bytes(bytes(b))
    return src


def truncated_jpeg(tmp):
    src = _ok(tmp)
    p = src / "rgb" / "000001.jpg"
    p.write_bytes(p.read_bytes()[:200])
    return src


def text_as_png(tmp):
    src = _ok(tmp)
    (src / "masks" / "000001.png").write_text("not an image")
    return src


def stray_file_in_rgb(tmp):
    src = _ok(tmp)
    (src / "rgb" / "notes.txt").write_text("x")
    return src


def bad_json(tmp):
    src = _ok(tmp)
    (src / "session.json").write_text('{"format": "vysics-session/1",\n "fps": 30,,}')
    return pack(src, tmp / "a.zip", "zip")


def json_nan(tmp):
    src = _ok(tmp)
    (src / "session.json").write_text((src / "session.json").read_text().replace('"fps": 10.0', '"fps": NaN'))
    return src


def json_not_object(tmp):
    src = _ok(tmp)
    (src / "session.json").write_text("[1, 2]")
    return src


def nan_in_robot(tmp):
    rows = [["t", "ee_x", "ee_y", "ee_z"]] + [[0.1 * i - 0.05, 0.3, 0.0, 0.05] for i in range(6)]
    rows[3][2] = "nan"
    return _ok(tmp, Spec(robot_rows=rows))


def inf_in_robot(tmp):
    rows = [["t", "ee_x", "ee_y", "ee_z"]] + [[0.1 * i - 0.05, 0.3, 0.0, 0.05] for i in range(6)]
    rows[5][3] = "inf"
    return _ok(tmp, Spec(robot_rows=rows))


def text_in_robot(tmp):
    rows = [["t", "ee_x", "ee_y", "ee_z"]] + [[0.1 * i - 0.05, 0.3, 0.0, 0.05] for i in range(6)]
    rows[2][1] = "abc"
    return _ok(tmp, Spec(robot_rows=rows))


def robot_not_increasing(tmp):
    rows = [["t", "ee_x", "ee_y", "ee_z"]] + [[0.1 * i - 0.05, 0.3, 0.0, 0.05] for i in range(6)]
    rows[4][0] = rows[3][0]
    return _ok(tmp, Spec(robot_rows=rows))


def robot_short_span(tmp):
    rows = [["t", "ee_x", "ee_y", "ee_z"]] + [[0.05 * i, 0.3, 0.0, 0.05] for i in range(4)]  # ends at 0.15 < 0.3
    return _ok(tmp, Spec(robot_rows=rows))


def robot_missing_columns(tmp):
    rows = [["t", "x", "y", "z"]] + [[0.1 * i - 0.05, 0.3, 0.0, 0.05] for i in range(6)]
    return _ok(tmp, Spec(robot_rows=rows))


def robot_joints_without_flag(tmp):
    rows = [["t"] + [f"q{i}" for i in range(1, 8)]] + [[0.1 * i - 0.05] + [0.0, 0, 0, -1.5, 0, 1.5, 0.7] for i in range(6)]
    return _ok(tmp, Spec(robot_rows=rows))


def robot_joints_in_degrees(tmp):
    rows = [["t"] + [f"q{i}" for i in range(1, 8)]] + [[0.1 * i - 0.05] + [0.0, 0, 0, -90.0, 0, 90, 45] for i in range(6)]
    return _ok(tmp, Spec(robot_rows=rows, meta={"robot": {"joints": "franka_panda"}}))


def robot_ragged_row(tmp):
    rows = [["t", "ee_x", "ee_y", "ee_z"]] + [[0.1 * i - 0.05, 0.3, 0.0, 0.05] for i in range(6)]
    rows[2] = rows[2][:3]
    return _ok(tmp, Spec(robot_rows=rows))


def robot_partial_cmd(tmp):
    rows = [["t", "ee_x", "ee_y", "ee_z", "cmd_x"]] + [[0.1 * i - 0.05, 0.3, 0.0, 0.05, 0.3] for i in range(6)]
    return _ok(tmp, Spec(robot_rows=rows))


def rigid_bad(tmp):
    T = np.eye(4)
    T[:3, :3] *= 1.2
    T[:3, 3] = [0, 0, 1]
    return _json(tmp, camera={"T_world_camera": T.tolist()})


def rigid_reflection(tmp):
    T = np.diag([1.0, 1.0, -1.0, 1.0])
    return _json(tmp, camera={"T_world_camera": T.tolist()})


def rigid_last_row(tmp):
    T = np.eye(4)
    T[3, 0] = 0.5
    return _json(tmp, camera={"T_world_camera": T.tolist()})


def mutate_json(tmp, **patch):
    return _json(tmp, **patch)


CASES = {
    # name: (builder, expected file (substring), expected rule (substring))
    "traversal_tar": (traversal_tar, "../evil.txt", "'..'"),
    "traversal_zip": (traversal_zip, "rgb/../../evil.txt", "'..'"),
    "absolute_zip": (absolute_zip, "/tmp/evil.txt", "absolute path"),
    "absolute_tar": (absolute_tar, "/tmp/evil.txt", "absolute path"),
    "symlink_tar": (symlink_tar, "rgb/link.jpg", "symbolic link"),
    "hardlink_tar": (hardlink_tar, "notes.txt", "hard link"),
    "device_tar": (device_tar, "dev", "special file"),
    "symlink_zip": (symlink_zip, "rgb/link.jpg", "symbolic link"),
    "symlink_folder": (symlink_folder, "notes.txt", "symbolic link"),
    "zip_bomb": (zip_bomb, "a.zip", "compression ratio"),
    "tgz_bomb": (tgz_bomb, "a.tgz", "compression ratio"),
    "zip_lying_header": (zip_lying_header, "padding.bin", "corrupt"),
    "truncated_zip": (truncated_zip, "a.zip", "corrupt or truncated"),
    "truncated_tgz": (truncated_tgz, "a.tgz", "corrupt or truncated"),
    "truncated_tar": (truncated_tar, "a.tar", "corrupt or truncated"),
    "corrupt_zip_member": (corrupt_zip_member, "robot.csv", "corrupt"),
    "not_an_archive": (not_an_archive, "a.zip", "not a zip, tar"),
    "two_top_folders": (two_top_folders, "a.zip", "exactly one top-level folder"),
    "duplicate_member": (duplicate_member, "robot.csv", "duplicate"),
    "missing_session_json": (missing_session_json, "session.json", "missing"),
    "missing_robot_csv": (missing_robot_csv, "robot.csv", "missing"),
    "missing_depth_frame": (missing_depth_frame, "depth/000002.png", "missing"),
    "extra_depth_frame": (extra_depth_frame, "depth/000003.png", "no colour frame"),
    "missing_masks_folder": (missing_masks_folder, "masks/", "missing folder"),
    "depth_8bit": (depth_8bit, "depth/000001.png", "8-bit image, expected 16-bit"),
    "depth_rgb": (depth_rgb, "depth/000001.png", "expected single-channel 16-bit"),
    "depth_jpeg": (depth_jpeg, "depth/000001.jpg", "expected a single-channel 16-bit PNG"),
    "mask_16bit": (mask_16bit, "masks/000000.png", "16-bit image, expected 8-bit"),
    "rgb_grayscale": (rgb_grayscale, "rgb/000002.jpg", "grayscale"),
    "rgb_wrong_size": (rgb_wrong_size, "rgb/000002.jpg", "40x30 image, expected 32x24"),
    "mask_wrong_size": (mask_wrong_size, "masks/000003.png", "40x30 image, expected 32x24"),
    "truncated_png": (truncated_png, "depth/000002.png", "truncated PNG"),
    "bitflip_png": (bitflip_png, "depth/000002.png", "CRC"),
    "truncated_jpeg": (truncated_jpeg, "rgb/000001.jpg", "JPEG"),
    "text_as_png": (text_as_png, "masks/000001.png", "not a PNG"),
    "stray_file_in_rgb": (stray_file_in_rgb, "rgb/notes.txt", "unexpected file"),
    "bad_json": (bad_json, "session.json", "invalid JSON at line 2"),
    "json_nan": (json_nan, "session.json", "NaN"),
    "json_not_object": (json_not_object, "session.json", "JSON object"),
    "nan_in_robot": (nan_in_robot, "robot.csv", "row 4: ee_y is nan, expected a finite number"),
    "inf_in_robot": (inf_in_robot, "robot.csv", "row 6: ee_z is inf"),
    "text_in_robot": (text_in_robot, "robot.csv", "row 3: ee_x = 'abc' is not a number"),
    "robot_not_increasing": (robot_not_increasing, "robot.csv", "row 5: t"),
    "robot_short_span": (robot_short_span, "robot.csv", "cover every frame"),
    "robot_missing_columns": (robot_missing_columns, "robot.csv", "ee_x,ee_y,ee_z"),
    "robot_joints_without_flag": (robot_joints_without_flag, "robot.csv", "franka_panda"),
    "robot_joints_in_degrees": (robot_joints_in_degrees, "robot.csv", "row 2: q4 = -90 rad is outside the Panda joint range"),
    "robot_ragged_row": (robot_ragged_row, "robot.csv", "row 3: 3 fields"),
    "robot_partial_cmd": (robot_partial_cmd, "robot.csv", "cmd_x,cmd_y,cmd_z"),
    "unknown_format": (lambda t: mutate_json(t, format="vysics-session/2"), "session.json", "unsupported format 'vysics-session/2'"),
    "missing_format": (lambda t: mutate_json(t, format=DELETE), "session.json", "format: required field is missing"),
    "K_wrong_shape": (lambda t: mutate_json(t, camera={"K": [[1, 0, 0], [0, 1, 0]]}), "session.json", "camera.K: must be a 3x3"),
    "K_transposed": (lambda t: mutate_json(t, camera={"K": [[40, 0, 0], [0, 40, 0], [15.5, 11.5, 1]]}), "session.json", "camera.K"),
    "K_missing_no_file": (lambda t: mutate_json(t, camera={"K": DELETE}), "session.json", "cam_K.txt"),
    "K_pp_outside": (lambda t: mutate_json(t, camera={"K": [[40, 0, 150], [0, 40, 11.5], [0, 0, 1]]}), "session.json", "principal point"),
    "T_non_rigid": (rigid_bad, "session.json", "camera.T_world_camera: not a rigid transform"),
    "T_reflection": (rigid_reflection, "session.json", "reflection"),
    "T_last_row": (rigid_last_row, "session.json", "last row"),
    "T_wrong_shape": (lambda t: mutate_json(t, camera={"T_world_camera": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}), "session.json", "4x4"),
    "depth_scale_zero": (lambda t: mutate_json(t, camera={"depth_scale": 0}), "session.json", "camera.depth_scale"),
    "depth_scale_string": (lambda t: mutate_json(t, camera={"depth_scale": "0.001"}), "session.json", "camera.depth_scale"),
    "fps_and_frame_times": (lambda t: mutate_json(t, frame_times=[0, 0.1, 0.2, 0.3]), "session.json", "exactly one of fps or frame_times"),
    "neither_fps_nor_times": (lambda t: mutate_json(t, fps=None), "session.json", "exactly one of fps or frame_times"),
    "frame_times_count": (lambda t: mutate_json(t, fps=None, frame_times=[0, 0.1, 0.2]), "session.json", "frame_times has 3 entries but rgb/ holds 4"),
    "frame_times_decreasing": (lambda t: mutate_json(t, fps=None, frame_times=[0, 0.2, 0.1, 0.3]), "session.json", "strictly increasing"),
    "fps_negative": (lambda t: mutate_json(t, fps=-30), "session.json", "fps"),
    "ee_radius_zero": (lambda t: mutate_json(t, robot={"ee_radius": 0}), "session.json", "robot.ee_radius"),
    "ee_radius_mm": (lambda t: mutate_json(t, robot={"ee_radius": 19.5}), "session.json", "millimetres"),
    "ee_radius_missing": (lambda t: mutate_json(t, robot={"ee_radius": DELETE}), "session.json", "robot.ee_radius: required"),
    "unknown_robot": (lambda t: mutate_json(t, robot={"joints": "ur5"}), "session.json", "unsupported robot 'ur5'"),
    "tip_offset_len": (lambda t: mutate_json(t, robot={"joints": "franka_panda", "tip_offset": [0, 0.1]}), "session.json", "robot.tip_offset"),
    "table_height_string": (lambda t: mutate_json(t, table={"height": "low"}), "session.json", "table.height"),
    "mass_zero": (lambda t: mutate_json(t, object={"mass": 0}), "session.json", "object.mass"),
    "mass_negative": (lambda t: mutate_json(t, object={"mass": -1.0}), "session.json", "object.mass"),
    "friction_negative": (lambda t: mutate_json(t, friction={"object_table": -0.1}), "session.json", "friction.object_table"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_upload(case, tmp_path):
    build, file_part, rule_part = CASES[case]
    work = tmp_path / "work"
    work.mkdir()
    source = build(work)
    before = tree(tmp_path)
    dest = tmp_path / "staging" / "s1"
    with pytest.raises(InvalidSession) as ei:
        ingest(source, dest)
    e = ei.value
    assert file_part in e.file, (e.file, e.rule)
    assert rule_part in e.rule, (e.file, e.rule)
    assert str(e) == f"{e.file}: {e.rule}"
    assert not dest.exists() and not (tmp_path / "staging").exists()
    assert tree(tmp_path) == before  # nothing else touched (no escaped files)
    assert not Path("/tmp/evil.txt").exists() or Path("/tmp/evil.txt").read_bytes() != b"pwned"


def test_existing_empty_dest_is_kept_empty(tmp_path):
    src = write_session(tmp_path / "src")
    (src / "robot.csv").unlink()
    dest = tmp_path / "d"
    dest.mkdir()
    with pytest.raises(InvalidSession):
        ingest(src, dest)
    assert dest.is_dir() and not any(dest.iterdir())


@pytest.mark.parametrize(
    "limits,rule",
    [
        (Limits(max_entries=10), "max_entries"),
        (Limits(max_unpacked_bytes=5000), "max_unpacked_bytes"),
        (Limits(max_frames=3), "max_frames"),
        (Limits(max_width=16), "max_width"),
        (Limits(max_upload_bytes=1000), "max_upload_bytes"),
    ],
)
def test_limits(limits, rule, tmp_path):
    src = write_session(tmp_path / "src")
    arc = pack(src, tmp_path / "a.tgz", "tgz")
    with pytest.raises(InvalidSession) as ei:
        ingest(arc, tmp_path / "d", limits=limits)
    assert rule in ei.value.rule
    assert not (tmp_path / "d").exists()


def test_missing_upload(tmp_path):
    with pytest.raises(InvalidSession) as ei:
        ingest(tmp_path / "nope.zip", tmp_path / "d")
    assert ei.value.file == "nope.zip"
    assert not (tmp_path / "d").exists()


def test_no_table_plane_found(tmp_path):
    """table.height null but the camera pose puts the 'table' on a wall: no horizontal plane."""
    from tests.session.conftest import X_WC_default

    # rotate the world 90 deg about x: the real table becomes vertical in the declared world frame
    Rx = np.array([[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1.0]])
    src = write_session(tmp_path / "src", Spec(meta={"table": {"height": None}}))
    meta = json.loads((src / "session.json").read_text())
    meta["camera"]["T_world_camera"] = (Rx @ X_WC_default()).tolist()
    (src / "session.json").write_text(json.dumps(meta))
    with pytest.raises(InvalidSession) as ei:
        ingest(src, tmp_path / "d")
    assert ei.value.file == "depth/" and "no horizontal table plane" in ei.value.rule
    assert not (tmp_path / "d").exists()


def test_stray_file_next_to_top_folder(tmp_path):
    src = write_session(tmp_path / "src")
    arc = pack(src, tmp_path / "a.zip", "zip", top="s")
    with zipfile.ZipFile(arc, "a") as zf:
        zf.writestr("README.txt", b"hello")
    with pytest.raises(InvalidSession, match="exactly one top-level folder; found 'README.txt', 's'"):
        ingest(arc, tmp_path / "d")
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize("folder,value,rule", [("masks", np.uint8, "every mask is empty"), ("depth", np.uint16, "every depth frame is empty")])
def test_all_empty_masks_or_depth(folder, value, rule, tmp_path):
    src = write_session(tmp_path / "src")
    for p in (src / folder).iterdir():
        cv2.imwrite(str(p), np.zeros((24, 32), value))
    with pytest.raises(InvalidSession) as ei:
        ingest(src, tmp_path / "d")
    assert ei.value.file == f"{folder}/" and rule in ei.value.rule
    assert not (tmp_path / "d").exists()


def test_object_visible_in_one_unsampled_frame_is_enough(tmp_path):
    src = write_session(tmp_path / "src", Spec(n=6))
    masks = sorted((src / "masks").iterdir())
    for k, p in enumerate(masks):
        if k != 1:  # frames 0, 2/3 and 5 are the decoded sample
            cv2.imwrite(str(p), np.zeros((24, 32), np.uint8))
    assert ingest(src, tmp_path / "d").n_frames == 6
