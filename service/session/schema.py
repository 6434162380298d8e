"""Pydantic models of ``session.json`` (format ``vysics-session/1``) and the parsing of it.

Numbers are strict (a string "0.001" or ``true`` is not a number) and must be finite. Unknown keys are
kept and ignored, so newer writers stay readable. Every violation becomes
``InvalidSession("session.json", "<dotted.path>: <rule>")``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from service.errors import InvalidSession

FORMAT = "vysics-session/1"
SUPPORTED_JOINTS = ("franka_panda",)
DEFAULT_TIP_OFFSET = (0.0, 0.0, 0.1265)  # m in panda_link8; 0.107 + 0.1265 = 0.2335 m from panda_link7

MAX_JSON_BYTES = 16 << 20

_CFG = ConfigDict(extra="allow", strict=True, allow_inf_nan=False)


class Camera(BaseModel):
    model_config = _CFG
    K: list[list[float]] | None = None
    depth_scale: float = Field(gt=0)
    T_world_camera: list[list[float]]

    @field_validator("K")
    @classmethod
    def _k(cls, K: list[list[float]] | None) -> list[list[float]] | None:
        if K is None:
            return K
        check_K(np.asarray(K, dtype=float) if _is_3x3(K) else None)
        return K

    @field_validator("T_world_camera")
    @classmethod
    def _t(cls, T: list[list[float]]) -> list[list[float]]:
        if len(T) != 4 or any(len(r) != 4 for r in T):
            raise ValueError(f"must be a 4x4 matrix, got {len(T)} rows of lengths {[len(r) for r in T]}")
        M = np.asarray(T, dtype=float)
        if np.abs(M[3] - [0, 0, 0, 1]).max() > 1e-6:
            raise ValueError(f"last row must be [0, 0, 0, 1], got {M[3].tolist()}")
        R = M[:3, :3]
        err = np.abs(R.T @ R - np.eye(3)).max()
        if err > 1e-3:
            raise ValueError(
                f"not a rigid transform: the rotation block is not orthonormal (max |R^T R - I| = {err:.3g}); "
                "scale or shear is not allowed"
            )
        if np.linalg.det(R) < 0:
            raise ValueError("not a rigid transform: the rotation block is a reflection (det < 0)")
        return T


def _is_3x3(K: Any) -> bool:
    return isinstance(K, list) and len(K) == 3 and all(isinstance(r, list) and len(r) == 3 for r in K)


def check_K(K: np.ndarray | None) -> np.ndarray:
    """Validate a pinhole intrinsic matrix [[fx,s,cx],[0,fy,cy],[0,0,1]]; raises ValueError."""
    if K is None or K.shape != (3, 3):
        raise ValueError("must be a 3x3 matrix [[fx,0,cx],[0,fy,cy],[0,0,1]]")
    if not np.isfinite(K).all():
        raise ValueError("must hold finite numbers")
    if np.abs(K[2] - [0, 0, 1]).max() > 1e-6 or abs(K[1, 0]) > 1e-9:
        raise ValueError(f"must be upper triangular with last row [0, 0, 1] (got {K.tolist()}; transposed?)")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"focal lengths fx, fy must be > 0 (got {K[0, 0]:g}, {K[1, 1]:g})")
    return K


class Robot(BaseModel):
    model_config = _CFG
    ee_radius: float = Field(gt=0)
    joints: str | None = None
    tip_offset: list[float] | None = None

    @field_validator("ee_radius")
    @classmethod
    def _r(cls, r: float) -> float:
        if r > 0.5:
            raise ValueError(f"{r:g} m is not a plausible sphere radius (metres expected, not millimetres)")
        return r

    @field_validator("joints")
    @classmethod
    def _j(cls, j: str | None) -> str | None:
        if j is not None and j not in SUPPORTED_JOINTS:
            raise ValueError(f"unsupported robot '{j}'; use null (robot.csv gives ee_x,ee_y,ee_z) or 'franka_panda'")
        return j

    @field_validator("tip_offset")
    @classmethod
    def _o(cls, o: list[float] | None) -> list[float] | None:
        if o is not None and len(o) != 3:
            raise ValueError(f"must be 3 numbers [x, y, z] in metres in the flange frame, got {len(o)}")
        return o


class Table(BaseModel):
    model_config = _CFG
    height: float | None = None


class FrictionPriors(BaseModel):
    model_config = _CFG
    object_table: float = Field(0.26, ge=0)
    object_robot: float = Field(0.15, ge=0)


class ObjectInfo(BaseModel):
    model_config = _CFG
    mass: float | None = Field(None, gt=0)


class SessionMeta(BaseModel):
    """``session.json``."""

    model_config = _CFG
    format: str
    name: str | None = None
    fps: float | None = Field(None, gt=0)
    frame_times: list[float] | None = None
    camera: Camera
    robot: Robot
    table: Table = Table()
    friction: FrictionPriors = FrictionPriors()
    object: ObjectInfo = ObjectInfo()

    @field_validator("format")
    @classmethod
    def _fmt(cls, f: str) -> str:
        if f != FORMAT:
            raise ValueError(f"unsupported format '{f}'; this service reads '{FORMAT}'")
        return f

    @field_validator("frame_times")
    @classmethod
    def _ft(cls, ft: list[float] | None) -> list[float] | None:
        if ft is None:
            return ft
        if len(ft) == 0:
            raise ValueError("must not be empty")
        d = np.diff(np.asarray(ft, dtype=float))
        if (d <= 0).any():
            i = int(np.argmax(d <= 0)) + 1
            raise ValueError(f"must be strictly increasing (frame_times[{i}] = {ft[i]:g} <= frame_times[{i - 1}] = {ft[i - 1]:g})")
        return ft

    @model_validator(mode="after")
    def _fps_xor(self) -> SessionMeta:
        if (self.fps is None) == (self.frame_times is None):
            both = "both are given" if self.fps is not None else "neither is given"
            raise ValueError(f"give exactly one of fps or frame_times ({both})")
        return self


def _format_error(e: ValidationError) -> str:
    err = e.errors()[0]
    loc = ".".join(str(p) for p in err["loc"])
    msg = err["msg"]
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, ") :]
    if err["type"] == "missing":
        msg = "required field is missing"
    return f"{loc}: {msg}" if loc else msg


def parse_session_json(path: Path) -> SessionMeta:
    rel = "session.json"
    if not path.is_file():
        raise InvalidSession(rel, "missing (required)")
    if path.stat().st_size > MAX_JSON_BYTES:
        raise InvalidSession(rel, f"over {MAX_JSON_BYTES} bytes; session.json holds metadata only")
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise InvalidSession(rel, "not UTF-8 text") from None

    def _no_nan(c: str) -> float:
        raise ValueError(f"{c} is not allowed in JSON; use finite numbers")

    try:
        data = json.loads(text, parse_constant=_no_nan)
    except json.JSONDecodeError as e:
        raise InvalidSession(rel, f"invalid JSON at line {e.lineno} column {e.colno}: {e.msg}") from None
    except ValueError as e:
        raise InvalidSession(rel, f"invalid JSON: {e}") from None
    if not isinstance(data, dict):
        raise InvalidSession(rel, "must hold a JSON object at the top level")
    try:
        return SessionMeta.model_validate(data)
    except ValidationError as e:
        raise InvalidSession(rel, _format_error(e)) from None


def read_cam_K(path: Path) -> np.ndarray:
    rel = "cam_K.txt"
    try:
        vals = [float(x) for x in path.read_text(encoding="utf-8-sig").split()]
    except ValueError:
        raise InvalidSession(rel, "expected 3 rows of 3 whitespace-separated numbers") from None
    if len(vals) != 9:
        raise InvalidSession(rel, f"expected 9 numbers (a 3x3 matrix), found {len(vals)}")
    K = np.asarray(vals, dtype=float).reshape(3, 3)
    try:
        return check_K(K)
    except ValueError as e:
        raise InvalidSession(rel, str(e)) from None


def tip_offset(meta: SessionMeta) -> np.ndarray:
    o = meta.robot.tip_offset
    return np.asarray(DEFAULT_TIP_OFFSET if o is None else o, dtype=float)
