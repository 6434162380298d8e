"""Tiny synthetic sessions (32x24, a few frames): a flat table seen by a tilted camera, with a box on it."""

from __future__ import annotations

import io
import json
import tarfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pytest

W, H = 32, 24
K = np.array([[40.0, 0.0, 15.5], [0.0, 40.0, 11.5], [0.0, 0.0, 1.0]])


def look_at(c: np.ndarray, target: np.ndarray) -> np.ndarray:
    """X_WC of an OpenCV camera at c looking at target (world z up)."""
    z = target - c
    z = z / np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    X = np.eye(4)
    X[:3, :3] = np.stack([x, y, z], axis=1)
    X[:3, 3] = c
    return X


def render(X_WC, K, table_z, box_lo, box_hi, w=W, h=H, noise=0.0, rng=None):
    """Depth (m, along optical axis) and mask of a flat table z=table_z plus an axis-aligned box."""
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    r_C = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u, float)], axis=-1)
    r_W = r_C @ X_WC[:3, :3].T
    c = X_WC[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_table = (table_z - c[2]) / r_W[..., 2]
        t_table[t_table <= 0] = np.inf
        t0 = (np.asarray(box_lo) - c) / r_W
        t1 = (np.asarray(box_hi) - c) / r_W
    tmin = np.nanmax(np.minimum(t0, t1), axis=-1)
    tmax = np.nanmin(np.maximum(t0, t1), axis=-1)
    hit = (tmax >= tmin) & (tmin > 0)
    t_box = np.where(hit, tmin, np.inf)
    depth = np.minimum(t_table, t_box)
    mask = hit & (t_box <= t_table)
    depth[~np.isfinite(depth)] = 0.0
    if noise > 0:
        rng = rng or np.random.default_rng(0)
        depth = np.where(depth > 0, depth + rng.normal(0, noise, depth.shape), 0.0)
    return depth, mask


@dataclass
class Spec:
    n: int = 4
    fps: float = 10.0
    table_z: float = 0.02
    box: float = 0.12
    noise: float = 0.0
    rgb_ext: str = ".jpg"
    meta: dict = field(default_factory=dict)  # merged into session.json (DELETE removes a key)
    robot_rows: list | None = None  # replaces robot.csv rows (list of lists, first = header)


def X_WC_default() -> np.ndarray:
    return look_at(np.array([0.0, 0.05, 0.6]), np.array([0.5, 0.0, 0.0]))


def base_meta(spec: Spec) -> dict:
    return {
        "format": "vysics-session/1",
        "name": "tiny_push",
        "fps": spec.fps,
        "frame_times": None,
        "camera": {"K": K.tolist(), "depth_scale": 0.0001, "T_world_camera": X_WC_default().tolist()},
        "robot": {"ee_radius": 0.0195, "joints": None, "tip_offset": None},
        "table": {"height": spec.table_z},
        "friction": {"object_table": 0.3, "object_robot": 0.1},
        "object": {"mass": None},
    }


DELETE = object()  # in Spec.meta: remove this key from session.json


def _merge(d: dict, patch: dict) -> dict:
    for k, v in patch.items():
        if isinstance(v, dict) and isinstance(d.get(k), dict):
            _merge(d[k], v)
        elif v is DELETE:
            d.pop(k, None)
        else:
            d[k] = v
    return d



def robot_rows_default(n: int, fps: float) -> list[list]:
    t = np.linspace(-0.05, (n - 1) / fps + 0.05, 4 * n + 3)
    rows: list[list] = [["t", "ee_x", "ee_y", "ee_z", "cmd_x", "cmd_y", "cmd_z"]]
    for ti in t:
        rows.append([ti, 0.3 + 0.1 * ti, -0.1 + 0.05 * ti, 0.05, 0.31 + 0.1 * ti, -0.1, 0.05])
    return rows


def write_session(folder: Path, spec: Spec | None = None) -> Path:
    """Write a valid session (unless spec says otherwise) into ``folder``; returns ``folder``."""
    spec = spec or Spec()
    folder.mkdir(parents=True, exist_ok=True)
    meta = _merge(base_meta(spec), spec.meta)
    (folder / "session.json").write_text(json.dumps(meta, indent=1))
    for sub in ("rgb", "depth", "masks"):
        (folder / sub).mkdir(exist_ok=True)
    X_WC = X_WC_default()
    rng = np.random.default_rng(1)
    for i in range(spec.n):
        cx = 0.45 + 0.01 * i
        lo = [cx - spec.box / 2, -spec.box / 2, spec.table_z]
        hi = [cx + spec.box / 2, spec.box / 2, spec.table_z + spec.box]
        d, m = render(X_WC, K, spec.table_z, lo, hi, noise=spec.noise, rng=rng)
        stem = f"{i:06d}"
        d16 = np.clip(np.round(d / 0.0001), 0, 65535).astype(np.uint16)
        cv2.imwrite(str(folder / "depth" / f"{stem}.png"), d16)
        cv2.imwrite(str(folder / "masks" / f"{stem}.png"), (m * 255).astype(np.uint8))
        rgb = np.zeros((H, W, 3), np.uint8)
        rgb[..., 1] = 120
        rgb[m] = (30, 30, 200)
        cv2.imwrite(str(folder / "rgb" / f"{stem}{spec.rgb_ext}"), rgb)
    rows = spec.robot_rows if spec.robot_rows is not None else robot_rows_default(spec.n, spec.fps)
    (folder / "robot.csv").write_text("\n".join(",".join(str(x) for x in r) for r in rows) + "\n")
    return folder


def pack(folder: Path, out: Path, kind: str, top: str | None = None) -> Path:
    """Pack a session folder as zip / tar / tgz, at the root or under ``top/``."""
    files = sorted(p for p in folder.rglob("*") if p.is_file())
    arc = lambda p: (f"{top}/" if top else "") + p.relative_to(folder).as_posix()  # noqa: E731
    if kind == "zip":
        with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zf:
            for p in files:
                zf.write(p, arc(p))
    else:
        mode = "w:gz" if kind == "tgz" else "w"
        with tarfile.open(out, mode) as tf:
            for p in files:
                tf.add(p, arc(p))
    return out


def add_tar_member(tf: tarfile.TarFile, name: str, data: bytes = b"", **kw) -> None:
    ti = tarfile.TarInfo(name)
    ti.size = len(data)
    for k, v in kw.items():
        setattr(ti, k, v)
    tf.addfile(ti, io.BytesIO(data) if data else None)


@pytest.fixture
def session_dir(tmp_path: Path) -> Path:
    return write_session(tmp_path / "src")


@pytest.fixture
def make(tmp_path: Path):
    """make(spec=None, name='src') -> folder with a freshly written session."""
    counter = iter(range(1000))

    def _make(spec: Spec | None = None, name: str | None = None) -> Path:
        return write_session(tmp_path / (name or f"src{next(counter)}"), spec)

    return _make


def tree(p: Path) -> list[str]:
    return sorted(str(x.relative_to(p)) for x in p.rglob("*")) if p.exists() else []


__all__ = ["DELETE", "Spec", "write_session", "pack", "add_tar_member", "render", "look_at", "K", "W", "H", "tree"]
