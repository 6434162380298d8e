"""Session ingest: unpack an upload safely, validate every rule of ``vysics-session/1``, build ``Session``.

Order of checks (the first violation raises ``InvalidSession(file, rule)``; nothing is left in ``dest``):
container (``archive.unpack``) -> root folder -> ``session.json`` -> intrinsics (``camera.K`` or
``cam_K.txt``) -> frame listing (same stems in rgb/, depth/, masks/; count vs ``frame_times``; frame limit)
-> every image's header (format, bit depth, channels, size; PNG CRCs; JPEG EOI) plus a full decode of a
few frames -> ``robot.csv`` (columns, finite numbers, increasing t, coverage of the frame span, joint
ranges) -> forward kinematics when joints are given -> table plane when ``table.height`` is null.
Nothing under ``ground_truth/`` is read here; only its presence is recorded.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np

from service.errors import InvalidSession
from service.session import archive, images, robot
from service.session.schema import SessionMeta, parse_session_json, read_cam_K, tip_offset
from service.session.types import Friction, Session
from service.settings import Limits

Progress = Callable[[float, str], None] | None

RGB_EXT = (".png", ".jpg", ".jpeg")
JOINT_RANGE_MARGIN = 0.1  # rad beyond the URDF limits still accepted (encoder noise, calibration)
N_DECODE = 3  # frames per folder fully decoded during ingest


def _report(progress: Progress, f: float, msg: str) -> None:
    if progress is not None:
        progress(float(f), msg)


# --------------------------------------------------------------------------- hashing


def sha256_of(source: Path) -> str:
    """sha256 of an archive's bytes, or of a folder: sorted relative paths and file contents.

    Folder hash = sha256 over, for each regular file in sorted relative POSIX path order,
    ``path + NUL + sha256(content) + NUL``. Symbolic links contribute their target text.
    The ingest sidecar (``.vysics-ingest.json``) is skipped.
    """
    source = Path(source)
    if source.is_dir():
        h = hashlib.sha256()
        entries = []
        for parts, path, is_dir in archive.iter_folder(source):
            if is_dir or parts[-1] == archive.SIDECAR:
                if is_dir and path.is_symlink():
                    entries.append(("/".join(parts), b"L" + os.readlink(path).encode()))
                continue
            if path.is_symlink():
                entries.append(("/".join(parts), b"L" + os.readlink(path).encode()))
            else:
                entries.append(("/".join(parts), _file_sha(path)))
        for rel, digest in sorted(entries):
            h.update(rel.encode("utf-8", "surrogateescape") + b"\0" + digest + b"\0")
        return h.hexdigest()
    return _file_sha(source).hex()


def _file_sha(path: Path) -> bytes:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            h.update(chunk)
    return h.digest()


# --------------------------------------------------------------------------- frames


def _list_frames(root: Path, folder: str, exts: tuple[str, ...]) -> dict[str, Path]:
    d = root / folder
    if not d.is_dir():
        raise InvalidSession(f"{folder}/", "missing folder (required)")
    out: dict[str, Path] = {}
    for p in sorted(d.iterdir(), key=lambda p: p.name):
        rel = f"{folder}/{p.name}"
        if p.name.startswith("."):
            continue
        if p.is_dir():
            raise InvalidSession(rel, f"sub-folder in {folder}/; frames must sit directly in {folder}/")
        ext = p.suffix.lower()
        if ext not in exts:
            if folder != "rgb" and ext in (".jpg", ".jpeg"):
                kind = "single-channel 16-bit PNG" if folder == "depth" else "single-channel 8-bit PNG"
                raise InvalidSession(rel, f"JPEG file, expected a {kind}")
            raise InvalidSession(rel, f"unexpected file in {folder}/; frames must be {' or '.join(exts)}")
        stem = p.stem
        if stem in out:
            raise InvalidSession(rel, f"two frames with the stem '{stem}' ({out[stem].name} and {p.name})")
        out[stem] = p
    if not out:
        raise InvalidSession(f"{folder}/", "no frames (at least one is required)")
    return out


def _match_stems(rgb: dict[str, Path], other: dict[str, Path], folder: str) -> None:
    for stem, p in rgb.items():
        if stem not in other:
            raise InvalidSession(
                f"{folder}/{stem}.png", f"missing: colour frame rgb/{p.name} has no {folder} frame with the same stem"
            )
    for stem, p in other.items():
        if stem not in rgb:
            raise InvalidSession(f"{folder}/{p.name}", "no colour frame with the same stem in rgb/")


def _check_images(
    root: Path,
    files: dict[str, tuple[Path, ...]],
    limits: Limits,
    full: bool,
    progress: Progress,
) -> tuple[int, int]:
    """Check every frame's header (full) or just the first colour frame's (not full); -> (width, height)."""
    checks = {"rgb": images.check_rgb, "depth": images.check_depth, "masks": images.check_mask}
    kinds = {"rgb": "rgb", "depth": "depth", "masks": "mask"}
    first = files["rgb"][0]
    first_rel = f"rgb/{first.name}"
    info0 = images.image_info(first, first_rel, verify=full)
    images.check_rgb(info0, first_rel)
    W, H = info0.width, info0.height
    if W > limits.max_width or H > limits.max_height:
        raise InvalidSession(
            first_rel, f"{W}x{H} image exceeds the {limits.max_width}x{limits.max_height} limit (max_width/max_height)"
        )
    if not full:
        return W, H
    n = len(files["rgb"])
    total = 3 * n
    done = 0
    sample = sorted(set(np.linspace(0, n - 1, min(n, N_DECODE)).round().astype(int).tolist()))
    nonzero = {"depth": False, "masks": False}
    for folder in ("rgb", "depth", "masks"):
        for i, p in enumerate(files[folder]):
            rel = f"{folder}/{p.name}"
            info = images.image_info(p, rel, verify=True)
            checks[folder](info, rel)
            if (info.width, info.height) != (W, H):
                raise InvalidSession(rel, f"{info.width}x{info.height} image, expected {W}x{H} like {first_rel}")
            if i in sample:
                img = images.decode_check(p, rel, info, kinds[folder])
                if folder in nonzero and img.any():
                    nonzero[folder] = True
            done += 1
            if done % 64 == 0:
                _report(progress, 0.1 + 0.5 * done / total, f"checked {done}/{total} images")
    # the sampled frames were all zero: look at every frame before refusing
    if not nonzero["depth"] and not any(images.any_nonzero(p) for p in files["depth"]):
        raise InvalidSession("depth/", "every depth frame is empty (all pixels 0 = no reading)")
    if not nonzero["masks"] and not any(images.any_nonzero(p) for p in files["masks"]):
        raise InvalidSession("masks/", "every mask is empty; mark the object's pixels (non-zero) in the frames where it is visible")
    return W, H


# --------------------------------------------------------------------------- build


def _frame_times(meta: SessionMeta, n: int) -> np.ndarray:
    if meta.frame_times is not None:
        if len(meta.frame_times) != n:
            raise InvalidSession(
                "session.json", f"frame_times has {len(meta.frame_times)} entries but rgb/ holds {n} frames"
            )
        return np.asarray(meta.frame_times, dtype=float)
    assert meta.fps is not None
    return np.arange(n, dtype=float) / float(meta.fps)


def _robot_positions(meta: SessionMeta, log: robot.RobotLog) -> np.ndarray:
    if meta.robot.joints is None:
        assert log.ee is not None
        return log.ee
    from service.session.kinematics import PandaModel

    assert log.q is not None
    with PandaModel() as panda:
        lo, hi = panda.lower, panda.upper
        bad = (log.q < lo - JOINT_RANGE_MARGIN) | (log.q > hi + JOINT_RANGE_MARGIN)
        if bad.any():
            k, j = (int(x) for x in np.argwhere(bad)[0])
            raise InvalidSession(
                robot.REL,
                f"row {int(log.lines[k])}: q{j + 1} = {log.q[k, j]:g} rad is outside the Panda joint range "
                f"[{lo[j]:g}, {hi[j]:g}] (radians expected, not degrees)",
            )
        return panda.sphere_centres(log.q, tip_offset(meta))


def _detect_table(
    root: Path, K: np.ndarray, X_WC: np.ndarray, depth_scale: float, depth_files, mask_files, n_use: int = 5
) -> float:
    import cv2

    from service.session.table import TablePlaneConfig, detect_table_plane

    n = len(depth_files)
    idx = sorted(set(np.linspace(0, n - 1, min(n, n_use)).round().astype(int).tolist()))
    depths, masks = [], []
    for i in idx:
        d = cv2.imread(str(depth_files[i]), cv2.IMREAD_UNCHANGED)
        m = cv2.imread(str(mask_files[i]), cv2.IMREAD_UNCHANGED)
        depths.append(d.astype(np.float32) * np.float32(depth_scale))
        masks.append(m > 0)
    plane = detect_table_plane(depths, masks, K, X_WC, TablePlaneConfig())
    if plane is None:
        raise InvalidSession(
            "depth/",
            "table.height is null and no horizontal table plane was found below the object in the depth frames "
            "(check camera.T_world_camera and depth_scale, or give table.height in session.json)",
        )
    return plane.height


def build_session(
    root: Path,
    sha256: str,
    limits: Limits,
    *,
    full: bool,
    name: str | None = None,
    table_height: float | None = None,
    progress: Progress = None,
) -> Session:
    """Validate the unpacked session under ``root`` and build the typed Session.

    ``full`` checks every image (ingest); otherwise only the first frame's header is read for the sizes
    (``load_session`` on a folder that ingest already validated). ``table_height`` is a previously
    detected height to reuse when ``table.height`` is null.
    """
    meta = parse_session_json(root / "session.json")
    _report(progress, 0.05, "session.json is valid")
    if meta.camera.K is not None:
        K = np.asarray(meta.camera.K, dtype=float)
        k_file = "session.json"
    elif (root / "cam_K.txt").is_file():
        K = read_cam_K(root / "cam_K.txt")
        k_file = "cam_K.txt"
    else:
        raise InvalidSession("session.json", "camera.K is missing and there is no cam_K.txt; give the 3x3 intrinsic matrix")

    rgb = _list_frames(root, "rgb", RGB_EXT)
    depth = _list_frames(root, "depth", (".png",))
    masks = _list_frames(root, "masks", (".png",))
    _match_stems(rgb, depth, "depth")
    _match_stems(rgb, masks, "masks")
    stems = list(rgb.keys())  # sorted by file name
    n = len(stems)
    if n > limits.max_frames:
        raise InvalidSession("rgb/", f"{n} frames, over the limit of {limits.max_frames} (max_frames)")
    frame_times = _frame_times(meta, n)
    files = {
        "rgb": tuple(rgb[s] for s in stems),
        "depth": tuple(depth[s] for s in stems),
        "masks": tuple(masks[s] for s in stems),
    }
    W, H = _check_images(root, files, limits, full, progress)
    cx, cy = K[0, 2], K[1, 2]
    if not (0 <= cx <= W and 0 <= cy <= H):
        where = "camera.K" if k_file == "session.json" else "K"
        raise InvalidSession(k_file, f"{where}: principal point ({cx:g}, {cy:g}) lies outside the {W}x{H} image")
    _report(progress, 0.6, f"{n} frames of {W}x{H} are valid")

    log = robot.read_robot_csv(root / "robot.csv", meta.robot.joints)
    robot.check_coverage(log.t, frame_times)
    robot_p = _robot_positions(meta, log)
    p_WE = robot.interpolate(log.t, robot_p, frame_times)
    cmd_WE = robot.interpolate(log.t, log.cmd, frame_times) if log.cmd is not None else None
    _report(progress, 0.75, "robot.csv is valid")

    X_WC = np.asarray(meta.camera.T_world_camera, dtype=float)
    U, _, Vt = np.linalg.svd(X_WC[:3, :3])
    X_WC[:3, :3] = U @ Vt  # nearest rotation (the input is orthonormal to 1e-3)
    X_WC[3] = [0, 0, 0, 1]

    detected = meta.table.height is None
    if not detected:
        z_table = float(meta.table.height)  # type: ignore[arg-type]
    elif table_height is not None:
        z_table = float(table_height)
    else:
        _report(progress, 0.8, "detecting the table plane")
        z_table = _detect_table(root, K, X_WC, meta.camera.depth_scale, files["depth"], files["masks"])

    _report(progress, 1.0, "session is valid")
    aroot = root.resolve()
    return Session(
        name=meta.name or name or root.name,
        root=aroot,
        sha256=sha256,
        frame_times=frame_times,
        K=K,
        X_WC=X_WC,
        depth_scale=float(meta.camera.depth_scale),
        width=W,
        height=H,
        rgb_files=tuple(aroot / "rgb" / p.name for p in files["rgb"]),
        depth_files=tuple(aroot / "depth" / p.name for p in files["depth"]),
        mask_files=tuple(aroot / "masks" / p.name for p in files["masks"]),
        robot_t=log.t,
        robot_p_WE=np.asarray(robot_p, dtype=float),
        robot_cmd_WE=log.cmd,
        p_WE=p_WE,
        cmd_WE=cmd_WE,
        ee_radius=float(meta.robot.ee_radius),
        table_height=z_table,
        table_height_detected=detected,
        friction=Friction(float(meta.friction.object_table), float(meta.friction.object_robot)),
        mass=None if meta.object.mass is None else float(meta.object.mass),
        has_ground_truth=(root / "ground_truth").is_dir(),
    )


def _default_name(source: Path) -> str:
    n = source.name
    for suf in (".tar.gz", ".tgz", ".tar", ".zip"):
        if n.lower().endswith(suf):
            return n[: -len(suf)]
    return n


def _write_sidecar(s: Session) -> None:
    data = {"name": s.name, "table_height": s.table_height, "table_height_detected": s.table_height_detected}
    (s.root / archive.SIDECAR).write_text(json.dumps(data, indent=1))


def ingest(source: Path, dest: Path, *, limits: Limits | None = None, progress: Progress = None) -> Session:
    """Validate the upload ``source`` (folder, .zip, .tar, .tar.gz, .tgz) and unpack it into ``dest``.

    ``dest`` must not exist or be an empty folder; it is created. On any error everything created under it
    (and ``dest`` itself and any parents this call created) is removed and the error is raised:
    ``InvalidSession(file, rule)`` for input that breaks the format. Returns the validated ``Session``
    (``root`` = the folder under ``dest`` that holds session.json).
    """
    source, dest = Path(source), Path(dest)
    limits = limits if limits is not None else Limits()
    if not source.exists():
        raise InvalidSession(source.name, "upload not found")
    if dest.exists() and (not dest.is_dir() or any(dest.iterdir())):
        raise FileExistsError(f"ingest destination must be new or an empty folder: {dest}")
    if source.is_dir() and dest.resolve().is_relative_to(source.resolve()):
        raise ValueError(f"ingest destination {dest} lies inside the session folder {source}")
    created: list[Path] = []
    p = dest
    while not p.exists():
        created.append(p)
        p = p.parent
    dest.mkdir(parents=True, exist_ok=True)
    try:
        if not source.is_dir():
            archive.check_upload(source, limits)
        _report(progress, 0.0, "hashing the upload")
        sha = sha256_of(source)
        _report(progress, 0.02, "unpacking")
        archive.unpack(source, dest, limits)
        root = archive.find_root(dest, source.name)
        session = build_session(
            root, sha, limits, full=True, name=_default_name(source) if root == dest else root.name, progress=progress
        )
        _write_sidecar(session)
        return session
    except BaseException:
        _clean(dest, created)
        raise


def _clean(dest: Path, created: list[Path]) -> None:
    if dest.is_dir() and not dest.is_symlink():
        for child in list(dest.iterdir()):
            if child.is_dir() and not child.is_symlink():
                shutil.rmtree(child, ignore_errors=True)
            else:
                try:
                    child.unlink()
                except FileNotFoundError:
                    pass
    for p in created:  # innermost first
        try:
            p.rmdir()
        except OSError:
            break


def load_session(root: Path, sha256: str, *, limits: Limits | None = None) -> Session:
    """Re-read a session folder that ``ingest`` already validated (cheap: headers of one frame only).

    The detected table height and default name are taken from the ingest sidecar when present.
    """
    root = Path(root)
    side = root / archive.SIDECAR
    name = None
    table_height = None
    if side.is_file():
        try:
            data = json.loads(side.read_text())
        except (ValueError, OSError):
            data = {}  # unreadable: fall back to the defaults and to detecting the table again
        name = data.get("name") if isinstance(data.get("name"), str) else None
        h = data.get("table_height")
        if data.get("table_height_detected") and isinstance(h, (int, float)):
            table_height = float(h)
    return build_session(
        root, sha256, limits if limits is not None else Limits(), full=False, name=name, table_height=table_height
    )
