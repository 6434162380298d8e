"""A plain triangle mesh value shared by the stages (vertices in metres, in the frame named by the caller)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class Mesh:
    vertices: np.ndarray  # (V,3) float64, metres
    faces: np.ndarray  # (F,3) int64, counter-clockwise seen from outside

    def to_trimesh(self):
        import trimesh

        return trimesh.Trimesh(np.asarray(self.vertices, float), np.asarray(self.faces, np.int64), process=False)

    @staticmethod
    def from_trimesh(m) -> "Mesh":
        return Mesh(np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64))

    @staticmethod
    def load(path: Path) -> "Mesh":
        import trimesh

        m = trimesh.load(str(path), force="mesh", process=True)
        return Mesh.from_trimesh(m)

    def save_obj(self, path: Path) -> None:
        """Write a Wavefront OBJ (vertices and triangular faces only)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in np.asarray(self.vertices, float)]
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in np.asarray(self.faces, np.int64)]
        path.write_text("\n".join(lines) + "\n")

    @property
    def is_empty(self) -> bool:
        return len(self.faces) == 0
