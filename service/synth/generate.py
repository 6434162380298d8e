"""Assemble a synthetic session folder (format vysics-session/1) from a SynthSpec.

Pipeline: build the object (objects.py) -> lay out table, object and camera from the seed ->
simulate the interaction (sim.py, physics only) -> place the occluder (render.py, calibrated on the
object's silhouettes) -> render every frame, add sensor noise (noise.py) -> write the folder and the
sidecar ``<session>.effects.json`` next to it with the true hidden values.

Random streams: one numpy SeedSequence(seed) spawns independent generators for the scene layout,
the robot's plan, the occluder and the sensor noise, so switching noise or occlusion does not change
the motion. The same spec gives byte-identical files (on the same library versions).
"""

from __future__ import annotations

import io
import json
import os
import shutil
import tarfile
import tempfile
import time
import zipfile
from pathlib import Path

import cv2
import numpy as np

from service.mesh import Mesh
from service.synth import noise as _noise
from service.synth.camera import intrinsics, look_at
from service.synth.objects import KINDS, OBJECT_KINDS, make_object
from service.synth.render import Renderer, calibrate_occluder, hidden_fraction
from service.synth.sim import EE_RADIUS, controller, simulate
from service.synth.types import INTERACTIONS, OCCLUSION_LEVELS, PRESETS, HiddenEffects, SynthResult, SynthSpec
from service.transforms import mat_to_quat, rotation_angle

FORMAT = "vysics-session/1"
# azimuth of the camera around the object (world x points away from the robot base)
CAMERA_SIDES = {"side": -np.pi / 2, "front": 0.0, "other_side": np.pi / 2, "random": 0.0}
DEPTH_SCALE = 0.001


def sidecar_path(session_dir: Path) -> Path:
    """Where the hidden truth of ``session_dir`` is written: next to the folder, never inside it."""
    session_dir = Path(session_dir)
    return session_dir.parent / f"{session_dir.name}.effects.json"


def describe() -> dict:
    """Presets, object kinds, interactions, occlusion levels and hidden effects, for the command line."""
    return {
        "presets": {k: {"width": p.width, "height": p.height, "n_frames": p.n_frames, "fps": p.fps, "description": p.description} for k, p in PRESETS.items()},
        "objects": {k: {"description": v.description, "mass": v.mass} for k, v in KINDS.items()},
        "interactions": list(INTERACTIONS),
        "occlusion": dict(OCCLUSION_LEVELS),
        "effects": {k: str(v) for k, v in HiddenEffects().__dict__.items()},
    }


def _validate(spec: SynthSpec) -> None:
    if spec.object not in OBJECT_KINDS:
        raise ValueError(f"object {spec.object!r}: expected one of {list(OBJECT_KINDS)}")
    if spec.interaction not in INTERACTIONS:
        raise ValueError(f"interaction {spec.interaction!r}: expected one of {list(INTERACTIONS)}")
    if spec.camera_side not in CAMERA_SIDES:
        raise ValueError(f"camera_side {spec.camera_side!r}: expected one of {list(CAMERA_SIDES)}")
    if spec.rgb_format not in ("png", "jpg"):
        raise ValueError(f"rgb_format {spec.rgb_format!r}: expected png or jpg")
    w, h, n, fps = spec.frame_geometry()
    if w < 32 or h < 24 or n < 2 or fps <= 0:
        raise ValueError(f"frame geometry {w}x{h}, {n} frames at {fps} Hz is too small")
    spec.occlusion_target()
    if not isinstance(spec.mask_offset_px, int) or not abs(spec.mask_offset_px) < w // 4:
        raise ValueError(f"mask_offset_px {spec.mask_offset_px!r}: expected an integer with |value| < {w // 4} (a quarter of the width)")


def _contact_intervals(t: np.ndarray, c: np.ndarray, max_gap: int = 2, min_len: int = 2) -> list[tuple[float, float]]:
    """Merge per-step contact flags into [t_start, t_end] intervals (gaps <= max_gap steps bridged)."""
    idx = np.nonzero(c)[0]
    if len(idx) == 0:
        return []
    out = []
    a = b = idx[0]
    for k in idx[1:]:
        if k - b <= max_gap + 1:
            b = k
        else:
            out.append((a, b))
            a = b = k
    out.append((a, b))
    return [(float(t[a]), float(t[b])) for a, b in out if b - a + 1 >= min_len]


def _csv(header: str, rows: np.ndarray, fmt: str) -> str:
    buf = io.StringIO()
    np.savetxt(buf, rows, fmt=fmt, delimiter=",", header=header, comments="")
    return buf.getvalue()


def make_session(spec: SynthSpec, out_dir: Path, *, progress=None) -> SynthResult:
    """Generate the session folder ``out_dir`` (replaced if it holds a session) and its sidecar."""
    t_wall = time.perf_counter()
    _validate(spec)
    out_dir = Path(out_dir)
    if out_dir.exists() and any(out_dir.iterdir()) and not (out_dir / "session.json").exists():
        raise FileExistsError(f"{out_dir}: exists, is not empty and is not a session folder; refusing to overwrite")
    W, H, N, fps = spec.frame_geometry()
    ss = np.random.SeedSequence(int(spec.seed))
    rng_scene, rng_plan, rng_occ, rng_noise, rng_tex = (np.random.default_rng(s) for s in ss.spawn(5))

    def report(f: float, msg: str) -> None:
        if progress is not None:
            progress(float(min(max(f, 0.0), 1.0)), msg)

    # ----------------------------------------------------------------------------- scene layout
    obj = make_object(spec.object, spec.scale, spec.mass)
    table_h, start_xy, start_yaw, X_WC, lateral = scene_layout(spec, obj, rng_scene)
    K = intrinsics(W, H)
    shoulder = np.array([0.0, 0.0, table_h + 0.7])

    # ----------------------------------------------------------------------------- physics
    rec = simulate(
        obj, interaction=spec.interaction, table_h=table_h, start_xy=start_xy, start_yaw=start_yaw, lateral=lateral,
        n_frames=N, fps=fps, physics_hz=spec.physics_hz, mu_ot=spec.friction_object_table, mu_or=spec.friction_object_robot,
        effects=spec.effects, rng=rng_plan, log_margin=0.2 + abs(spec.effects.clock_offset),
        rolling_friction=spec.rolling_friction, progress=lambda f, m: report(0.25 * f, m),
    )

    # ----------------------------------------------------------------------------- rendering
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
    rend = Renderer(obj, table_h, K, X_WC, W, H, shoulder, rng_tex)
    try:
        target_occ = spec.occlusion_target()
        occluder = None
        if target_occ > 0:
            report(0.25, "placing occluders")
            occluder = calibrate_occluder(rend, obj, rec.X_WM, rec.frame_t, target_occ, rng_occ, p_WE=rec.ee_frames)
        for sub in ("rgb", "depth", "masks", "ground_truth"):
            (tmp / sub).mkdir(parents=True)
        hidden = np.full(N, np.nan)
        ext = spec.rgb_format
        for i in range(N):
            rend.pose_scene(rec.X_WM[i], rec.ee_frames[i], float(rec.frame_t[i]))
            rgb, z, mask = rend.render()
            hidden[i] = hidden_fraction(mask, rend.object_only_mask(rec.X_WM[i]))
            if spec.noise:
                z = _noise.noisy_depth(z, rng_noise)
                mask = _noise.noisy_mask(mask, rng_noise)
                rgb = _noise.noisy_rgb(rgb, rng_noise)
            if spec.mask_offset_px:
                mask, z = _noise.misregister_mask(mask, z, spec.mask_offset_px)
            d16 = np.clip(np.round(z / DEPTH_SCALE), 0, 65535).astype(np.uint16)
            stem = f"{i:06d}"
            bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
            if ext == "jpg":
                cv2.imwrite(str(tmp / "rgb" / f"{stem}.jpg"), bgr, [cv2.IMWRITE_JPEG_QUALITY, 92])
            else:
                cv2.imwrite(str(tmp / "rgb" / f"{stem}.png"), bgr)
            cv2.imwrite(str(tmp / "depth" / f"{stem}.png"), d16)
            cv2.imwrite(str(tmp / "masks" / f"{stem}.png"), mask.astype(np.uint8) * 255)
            if i % 5 == 0:
                report(0.3 + 0.68 * i / N, f"rendering frame {i + 1}/{N}")
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    finally:
        rend.close()

    # ----------------------------------------------------------------------------- files
    try:
        eff = spec.effects
        name = spec.session_name()
        session = {
            "format": FORMAT,
            "name": name,
            "fps": fps,
            "frame_times": None,
            "camera": {"K": K.tolist(), "depth_scale": DEPTH_SCALE, "T_world_camera": X_WC.tolist()},
            "robot": {"ee_radius": EE_RADIUS, "joints": None, "tip_offset": None},
            "table": {"height": table_h if spec.declare_table_height else None},
            "friction": {"object_table": spec.friction_object_table, "object_robot": spec.friction_object_robot},
            "object": {"mass": obj.mass if spec.declare_mass else None},
        }
        (tmp / "session.json").write_text(json.dumps(session, indent=2) + "\n")
        robot_p = _noise.noisy_robot(rec.robot_p, rng_noise) if spec.noise else rec.robot_p
        robot_rows = np.c_[rec.robot_t + eff.clock_offset, robot_p, rec.robot_cmd]
        (tmp / "robot.csv").write_text(_csv("t,ee_x,ee_y,ee_z,cmd_x,cmd_y,cmd_z", robot_rows, "%.6f"))
        Mesh.from_trimesh(obj.mesh).save_obj(tmp / "ground_truth" / "mesh.obj")
        q = mat_to_quat(rec.X_WM[:, :3, :3])
        pose_rows = np.c_[rec.frame_t, rec.X_WM[:, :3, 3], q]
        (tmp / "ground_truth" / "poses.csv").write_text(_csv("t,x,y,z,qw,qx,qy,qz", pose_rows, "%.9f"))
        # contact intervals on the frame clock, clipped to the span of the frames
        t_last = float(rec.frame_t[-1])
        contacts = [(max(a, 0.0), min(b, t_last)) for a, b in _contact_intervals(rec.robot_t, rec.contact) if b >= 0.0 and a <= t_last]
        crow = np.asarray(contacts, float).reshape(-1, 2)
        (tmp / "ground_truth" / "contacts.csv").write_text(_csv("t_start,t_end", crow, "%.6f"))

        if out_dir.exists():
            shutil.rmtree(out_dir)
        os.replace(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise

    valid = hidden[~np.isnan(hidden)]
    occ_mean = float(valid.mean()) if len(valid) else float("nan")
    in_band = float(np.mean((valid >= 0.4) & (valid <= 0.7))) if len(valid) else 0.0
    travel = float(np.linalg.norm(rec.X_WM[-1, :3, 3] - rec.X_WM[0, :3, 3]))
    rot = float(rotation_angle(rec.X_WM[0, :3, :3].T @ rec.X_WM[-1, :3, :3]))
    mu_true = eff.friction_object_table if eff.friction_object_table is not None else spec.friction_object_table
    mu_or_true = eff.friction_object_robot if eff.friction_object_robot is not None else spec.friction_object_robot
    sidecar = {
        "session": name,
        "spec": _jsonable(spec.to_dict()),
        "effects": _jsonable(eff.active()),
        "sim_effects": _sim_effects(spec),
        "true": {
            "mass": obj.mass,
            "com_mesh": rec.com_M.tolist(),
            "inertia_mesh": rec.inertia_M.tolist(),
            "friction_object_table": mu_true,
            "friction_object_robot": mu_or_true,
            "rolling_friction": spec.rolling_friction,
            "restitution": eff.restitution,
            "linear_damping": eff.linear_damping,
            "angular_damping": eff.angular_damping,
            "gravity": rec.gravity.tolist(),
            "table_height": table_h,
            "clock_offset": eff.clock_offset,
        },
        "declared": {"mass": session["object"]["mass"], "table_height": session["table"]["height"], "friction": session["friction"]},
        "object": {"kind": obj.kind, "scale": spec.scale, "description": KINDS[obj.kind].description, "convex": obj.convex, "extents": obj.extents.tolist(), "volume": float(obj.mesh.volume)},
        "robot_controller": {"law": "F = K (x_cmd - x) - D v + gravity compensation", "stiffness": controller(spec.interaction)[1], "damping": controller(spec.interaction)[2], "mass": controller(spec.interaction)[0], "physics_hz": spec.physics_hz},
        "strokes": list(rec.strokes),
        "occlusion": {
            "target": target_occ,
            "occluder": None if occluder is None else occluder.kind,
            "hidden_mean": occ_mean,
            "hidden_in_band_40_70": in_band,
            "hidden_per_frame": [None if np.isnan(h) else round(float(h), 4) for h in hidden],
        },
        "contacts": contacts,
        "motion": {"travel": travel, "rotation": rot},
        "noise": {"enabled": spec.noise, "depth_sigma": f"{_noise.DEPTH_SIGMA_A} + {_noise.DEPTH_SIGMA_B} z^2 m"},
    }
    side = sidecar_path(out_dir)
    side.write_text(json.dumps(sidecar, indent=2) + "\n")
    report(1.0, "done")
    return SynthResult(
        session_dir=out_dir, sidecar_path=side, n_frames=N, width=W, height=H, occlusion_mean=occ_mean,
        occlusion_per_frame=hidden, occlusion_in_band=in_band, contacts=tuple(contacts), object_travel=travel,
        object_rotation=rot, elapsed=time.perf_counter() - t_wall,
    )


def _sim_effects(spec: SynthSpec) -> dict[str, float]:
    """The departures from the plain rigid-body model, named as in service.sim.effects (name -> value)."""
    e = spec.effects
    out: dict[str, float] = {}
    if e.restitution:
        out["restitution"] = float(e.restitution)
    if e.linear_damping:
        out["linear_damping"] = float(e.linear_damping)
    if e.angular_damping:
        out["angular_damping"] = float(e.angular_damping)
    if e.table_tilt[0]:
        out["table_tilt_x"] = float(e.table_tilt[0])
    if e.table_tilt[1]:
        out["table_tilt_y"] = float(e.table_tilt[1])
    if e.clock_offset:
        out["clock_offset"] = float(e.clock_offset)
    if e.friction_object_table is not None:
        out["friction_object_table"] = float(e.friction_object_table)
    if e.friction_object_robot is not None and spec.friction_object_robot > 0:  # a factor on the declared mu_OR
        out["friction_scale_robot"] = float(e.friction_object_robot) / float(spec.friction_object_robot)
    if spec.rolling_friction:
        out["rolling_friction"] = float(spec.rolling_friction)
    return out


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    return x


def make_archive(session_dir: Path, archive_path: Path) -> Path:
    """Pack ``session_dir`` into .zip, .tar, .tar.gz or .tgz, inside one top-level folder, deterministically."""
    session_dir, archive_path = Path(session_dir), Path(archive_path)
    if not (session_dir / "session.json").is_file():
        raise FileNotFoundError(f"{session_dir}: no session.json")
    files = sorted(p for p in session_dir.rglob("*") if p.is_file())
    top = session_dir.name
    name = archive_path.name.lower()
    archive_path.parent.mkdir(parents=True, exist_ok=True)
    if name.endswith(".zip"):
        with zipfile.ZipFile(archive_path, "w", compression=zipfile.ZIP_DEFLATED) as z:
            for p in files:
                info = zipfile.ZipInfo(f"{top}/{p.relative_to(session_dir).as_posix()}", date_time=(2020, 1, 1, 0, 0, 0))
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = 0o644 << 16
                z.writestr(info, p.read_bytes())
    elif name.endswith((".tar.gz", ".tgz", ".tar")):
        import gzip

        raw = io.BytesIO()
        with tarfile.open(fileobj=raw, mode="w", format=tarfile.PAX_FORMAT) as t:
            for p in files:
                data = p.read_bytes()
                info = tarfile.TarInfo(f"{top}/{p.relative_to(session_dir).as_posix()}")
                info.size, info.mtime, info.mode = len(data), 0, 0o644
                t.addfile(info, io.BytesIO(data))
        if name.endswith(".tar"):
            archive_path.write_bytes(raw.getvalue())
        else:
            with open(archive_path, "wb") as f, gzip.GzipFile(fileobj=f, mode="wb", mtime=0, filename="") as g:
                g.write(raw.getvalue())
    else:
        raise ValueError(f"{archive_path}: expected a .zip, .tar, .tar.gz or .tgz name")
    return archive_path


def scene_layout(spec: SynthSpec, obj, rng_scene: np.random.Generator) -> tuple[float, np.ndarray, float, np.ndarray, np.ndarray]:
    """Table height, object start (xy (2,), yaw), camera pose X_WC (4,4) and the lateral push direction (2,) of a
    session, drawn from the scene stream of its seed (the first of the five streams of ``SeedSequence(seed)``)."""
    table_h = float(spec.table_height) if spec.table_height is not None else float(rng_scene.uniform(-0.05, 0.05))
    start_xy = np.array([0.5 + rng_scene.uniform(-0.04, 0.04), rng_scene.uniform(-0.04, 0.04)])
    start_yaw = float(rng_scene.uniform(-np.pi, np.pi))
    dist = float(spec.camera_distance) if spec.camera_distance is not None else float(rng_scene.uniform(0.6, 0.9))
    az = CAMERA_SIDES.get(spec.camera_side, 0.0) + rng_scene.uniform(-0.45, 0.45)
    el = rng_scene.uniform(0.5, 0.8)
    if spec.camera_side == "random":
        az += float(rng_scene.choice([-np.pi / 2, 0.0, np.pi / 2]))
    target = np.array([start_xy[0], start_xy[1], table_h + 0.45 * float(obj.extents[2])])
    eye = target + dist * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    X_WC = look_at(eye, target)
    lateral = X_WC[:2, 0] / np.linalg.norm(X_WC[:2, 0])
    return table_h, start_xy, start_yaw, X_WC, lateral
