"""``robot.csv``: parsing, checks and linear interpolation of robot samples to the frame times.

Rows are samples (t_k, y_k), k = 0..M-1 with t strictly increasing. A frame at time s with
t_0 - tol <= s <= t_{M-1} + tol gets the piecewise-linear interpolant
y(s) = y_k + (s - t_k) / (t_{k+1} - t_k) * (y_{k+1} - y_k), held constant outside [t_0, t_{M-1}].
The tolerance is half a frame period (``coverage_tolerance``): a robot log that starts or stops within
half a frame of the video is accepted; a larger gap is an error.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from service.errors import InvalidSession

REL = "robot.csv"
EE_COLS = ("ee_x", "ee_y", "ee_z")
Q_COLS = tuple(f"q{i}" for i in range(1, 8))
CMD_COLS = ("cmd_x", "cmd_y", "cmd_z")
MAX_BYTES = 256 << 20  # ~3 million samples of 7 joints: hours at 1 kHz; bounds the parser's memory


@dataclass(frozen=True)
class RobotLog:
    t: np.ndarray  # (M,) s
    ee: np.ndarray | None  # (M,3) sphere centre in W, when given directly
    q: np.ndarray | None  # (M,7) joint angles, rad, with robot.joints
    cmd: np.ndarray | None  # (M,3) commanded sphere centre in W
    lines: np.ndarray  # (M,) line number of each sample in robot.csv (header = line 1), for messages


def read_robot_csv(path: Path, joints: str | None) -> RobotLog:
    """Parse and check robot.csv for a session whose ``robot.joints`` is ``joints``."""
    if not path.is_file():
        raise InvalidSession(REL, "missing (required)")
    size = path.stat().st_size
    if size > MAX_BYTES:
        raise InvalidSession(REL, f"{size} bytes, over the {MAX_BYTES}-byte limit for the robot log")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise InvalidSession(REL, "not UTF-8 text") from None
    rows = list(csv.reader(text.splitlines()))
    # drop blank lines, keep the line numbers for messages
    numbered = [(i + 1, r) for i, r in enumerate(rows) if r and any(c.strip() for c in r)]
    if not numbered:
        raise InvalidSession(REL, "empty file; expected a header row and samples")
    _, header = numbered[0]
    cols = [c.strip().lower() for c in header]
    if len(set(cols)) != len(cols):
        raise InvalidSession(REL, f"duplicate column names in header {cols}")
    idx = {c: i for i, c in enumerate(cols)}
    if "t" not in idx:
        raise InvalidSession(REL, f"header must have a 't' column (found {cols})")
    has_ee = all(c in idx for c in EE_COLS)
    has_q = all(c in idx for c in Q_COLS)
    if joints is None:
        if not has_ee:
            hint = (
                "; it has q1..q7: set robot.joints to \"franka_panda\" in session.json" if has_q else ""
            )
            raise InvalidSession(REL, f"header must have ee_x,ee_y,ee_z (robot.joints is null){hint}")
        need = ("t",) + EE_COLS
    else:
        if not has_q:
            raise InvalidSession(REL, f"header must have q1..q7 (robot.joints is \"{joints}\")")
        need = ("t",) + Q_COLS
    cmd_given = [c for c in CMD_COLS if c in idx]
    if cmd_given and len(cmd_given) != 3:
        raise InvalidSession(REL, f"give all of cmd_x,cmd_y,cmd_z or none (found {cmd_given})")
    if cmd_given:
        need = need + CMD_COLS
    body = numbered[1:]
    if len(body) < 2:
        raise InvalidSession(REL, f"needs at least 2 samples, found {len(body)}")
    for line, r in body:
        if len(r) != len(cols):
            raise InvalidSession(REL, f"row {line}: {len(r)} fields, header has {len(cols)}")
    sel = [idx[c] for c in need]
    cells = np.array([[r[j] for j in sel] for _, r in body], dtype=object)
    try:
        out = cells.astype(str).astype(float)
    except ValueError:
        out = None
    if out is None:  # find the first cell that is not a number, for the message
        for line, r in body:
            for c in need:
                s = r[idx[c]].strip()
                try:
                    float(s)
                except ValueError:
                    raise InvalidSession(REL, f"row {line}: {c} = '{s}' is not a number") from None
        raise InvalidSession(REL, "holds a value that is not a number")  # pragma: no cover
    bad = ~np.isfinite(out)
    if bad.any():
        k, j = (int(x) for x in np.argwhere(bad)[0])
        line, r = body[k]
        raise InvalidSession(REL, f"row {line}: {need[j]} is {r[idx[need[j]]].strip()}, expected a finite number")
    t = out[:, 0]
    dt = np.diff(t)
    if (dt <= 0).any():
        k = int(np.argmax(dt <= 0)) + 1
        raise InvalidSession(
            REL, f"row {body[k][0]}: t = {t[k]:g} is not greater than the previous t = {t[k - 1]:g} (t must strictly increase)"
        )
    ee = out[:, 1:4] if joints is None else None
    q = out[:, 1:8] if joints is not None else None
    cmd = out[:, -3:] if cmd_given else None
    return RobotLog(t=t, ee=ee, q=q, cmd=cmd, lines=np.array([ln for ln, _ in body]))


def coverage_tolerance(frame_times: np.ndarray) -> float:
    """Half the median frame period (or 1 ms for a single frame)."""
    if len(frame_times) < 2:
        return 1e-3
    return 0.5 * float(np.median(np.diff(frame_times)))


def check_coverage(robot_t: np.ndarray, frame_times: np.ndarray) -> None:
    tol = coverage_tolerance(frame_times)
    if frame_times[0] < robot_t[0] - tol or frame_times[-1] > robot_t[-1] + tol:
        raise InvalidSession(
            REL,
            f"samples span t = [{robot_t[0]:g}, {robot_t[-1]:g}] s but the frames span "
            f"[{frame_times[0]:g}, {frame_times[-1]:g}] s; the robot log must cover every frame "
            f"(tolerance {tol:g} s, half a frame period; same clock as the frames)",
        )


def interpolate(t: np.ndarray, y: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Linear interpolation of samples y (M,D) at times t (M,) to times s (N,) -> (N,D); ends held."""
    return np.stack([np.interp(s, t, y[:, d]) for d in range(y.shape[1])], axis=1)
