"""Reading a session's ``ground_truth/`` folder (evaluation only; nothing here reaches a model).

Files (all optional, spec/session-format.md): ``mesh.obj`` (true shape, metres, frame G),
``poses.csv`` (``t,x,y,z,qw,qx,qy,qz`` = X_WG per frame), ``contacts.csv`` (``t_start,t_end`` intervals of
annotated robot–object contact, inclusive).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from service.errors import InvalidSession
from service.mesh import Mesh
from service.transforms import xyzquat_to_pose

POSE_COLUMNS = ["t", "x", "y", "z", "qw", "qx", "qy", "qz"]
CONTACT_COLUMNS = ["t_start", "t_end"]


@dataclass(frozen=True)
class GroundTruth:
    mesh: Mesh | None  # true shape in its own frame G
    t: np.ndarray | None  # (N,) s
    X_WG: np.ndarray | None  # (N,4,4) true pose of G per frame
    contacts: np.ndarray | None  # (K,2) s, [t_start, t_end] inclusive

    def contact_at(self, t: np.ndarray) -> np.ndarray:
        """(N,) bool: annotated contact at times ``t``."""
        t = np.asarray(t, float)
        if self.contacts is None or len(self.contacts) == 0:
            return np.zeros(len(t), bool)
        c = self.contacts
        return ((t[:, None] >= c[None, :, 0] - 1e-9) & (t[:, None] <= c[None, :, 1] + 1e-9)).any(1)


def _read_table(path: Path, columns: list[str], rel: str) -> np.ndarray:
    try:
        with open(path, newline="") as fh:
            rows = [r for r in csv.reader(fh) if r and any(x.strip() for x in r)]
    except (OSError, UnicodeDecodeError) as e:
        raise InvalidSession(rel, f"cannot be read as text CSV ({e})") from None
    if not rows:
        raise InvalidSession(rel, f"empty file, expected a header row {','.join(columns)}")
    header = [h.strip() for h in rows[0]]
    missing = [c for c in columns if c not in header]
    if missing:
        raise InvalidSession(rel, f"missing column(s) {missing} in header {header}; expected {','.join(columns)}")
    idx = [header.index(c) for c in columns]
    out = np.zeros((len(rows) - 1, len(columns)))
    for i, r in enumerate(rows[1:]):
        try:
            out[i] = [float(r[j]) for j in idx]
        except (ValueError, IndexError):
            raise InvalidSession(rel, f"row {i + 2}: expected {len(columns)} numbers, got {r}") from None
    if not np.all(np.isfinite(out)):
        raise InvalidSession(rel, "values must be finite numbers")
    return out


def load_ground_truth(session_root: Path) -> GroundTruth | None:
    """Read ``<session_root>/ground_truth/``; None when the folder does not exist.

    Raises :class:`InvalidSession` naming the file and the rule when a present file is malformed.
    """
    gt = Path(session_root) / "ground_truth"
    if not gt.is_dir():
        return None
    mesh = t = X = contacts = None
    if (gt / "mesh.obj").exists():
        try:
            mesh = Mesh.load(gt / "mesh.obj")
        except Exception as e:  # trimesh raises many kinds
            raise InvalidSession("ground_truth/mesh.obj", f"not a readable OBJ mesh ({e})") from None
        if mesh.is_empty:
            raise InvalidSession("ground_truth/mesh.obj", "mesh has no faces")
    if (gt / "poses.csv").exists():
        a = _read_table(gt / "poses.csv", POSE_COLUMNS, "ground_truth/poses.csv")
        if len(a) == 0:
            raise InvalidSession("ground_truth/poses.csv", "no pose rows")
        if np.any(np.diff(a[:, 0]) <= 0):
            raise InvalidSession("ground_truth/poses.csv", "times t must increase strictly")
        qn = np.linalg.norm(a[:, 4:8], axis=1)
        if np.any(np.abs(qn - 1) > 1e-3):
            raise InvalidSession("ground_truth/poses.csv", "quaternions qw,qx,qy,qz must have unit norm")
        t, X = a[:, 0], xyzquat_to_pose(a[:, 1:8])
    if (gt / "contacts.csv").exists():
        contacts = _read_table(gt / "contacts.csv", CONTACT_COLUMNS, "ground_truth/contacts.csv")
        if np.any(contacts[:, 1] < contacts[:, 0]):
            raise InvalidSession("ground_truth/contacts.csv", "t_end must not be before t_start")
    return GroundTruth(mesh, t, X, contacts)
