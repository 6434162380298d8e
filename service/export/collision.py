"""Convex collision pieces for pybullet from a (possibly non-convex) watertight mesh.

A dynamic body in pybullet collides through the convex hull of each collision mesh, so a
non-convex object is described by a set of convex pieces whose union approximates it.
If the mesh is convex up to ``cfg.convex_tolerance`` (vol(M) ≥ (1 − tol)·vol(hull M)), the exact
hull is the single piece. Otherwise the mesh is split by V-HACD (approximate convex decomposition on
a voxelisation of the solid, Mamou & Ghorbel 2009; the copy shipped with pybullet as ``p.vhacd``).
If V-HACD fails or returns nothing usable, the convex hull of the mesh is the fallback.
"""

from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from service.export.types import ExportConfig
from service.mesh import Mesh


def convex_hull(mesh: Mesh) -> Mesh:
    """Convex hull of the mesh vertices, outward faces. (V,3) -> hull Mesh."""
    import trimesh

    v = np.asarray(mesh.vertices, float)
    hull = trimesh.Trimesh(v, np.zeros((0, 3), np.int64), process=False).convex_hull
    return Mesh.from_trimesh(hull)


def _is_nearly_convex(mesh: Mesh, tol: float) -> bool:
    tm = mesh.to_trimesh()
    if not tm.is_watertight:
        return False
    vol = abs(float(tm.volume))
    hull_vol = float(tm.convex_hull.volume)
    return hull_vol > 0 and vol >= (1.0 - tol) * hull_vol


@contextmanager
def _quiet_stdout():
    """Send the C-level stdout of V-HACD (its progress lines) to /dev/null for the call."""
    try:
        fd = os.dup(1)
    except OSError:  # no stdout to redirect
        yield
        return
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            try:
                yield
            finally:
                os.dup2(fd, 1)
    finally:
        os.close(fd)


def parse_multi_obj(text: str) -> list[Mesh]:
    """Split an OBJ holding several ``o`` objects (global 1-based vertex numbering) into meshes."""
    verts: list[list[float]] = []
    groups: list[list[list[int]]] = []
    for line in text.splitlines():
        if line.startswith("o ") or line.startswith("g "):
            groups.append([])
        elif line.startswith("v "):
            verts.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("f "):
            if not groups:
                groups.append([])
            idx = [int(tok.split("/")[0]) for tok in line.split()[1:]]
            idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
            for k in range(1, len(idx) - 1):  # fan-triangulate polygons
                groups[-1].append([idx[0], idx[k], idx[k + 1]])
    V = np.asarray(verts, float).reshape(-1, 3)
    out = []
    for faces in groups:
        if not faces:
            continue
        F = np.asarray(faces, np.int64)
        used, inv = np.unique(F.ravel(), return_inverse=True)
        out.append(Mesh(V[used], inv.reshape(-1, 3).astype(np.int64)))
    return out


def _vhacd(mesh: Mesh, cfg: ExportConfig) -> list[Mesh]:
    import pybullet as p

    with tempfile.TemporaryDirectory(prefix="vhacd_") as tmp:
        src, dst, log = Path(tmp, "in.obj"), Path(tmp, "out.obj"), Path(tmp, "log.txt")
        mesh.save_obj(src)
        with _quiet_stdout():
            p.vhacd(
                str(src),
                str(dst),
                str(log),
                concavity=cfg.vhacd_concavity,
                resolution=int(cfg.vhacd_resolution),
                depth=int(cfg.vhacd_depth),
                maxNumVerticesPerCH=int(cfg.vhacd_max_vertices_per_hull),
                minVolumePerCH=cfg.vhacd_min_volume_per_hull,
                planeDownsampling=int(cfg.vhacd_plane_downsampling),
                convexhullDownsampling=int(cfg.vhacd_hull_downsampling),
            )
        if not dst.exists():
            return []
        return parse_multi_obj(dst.read_text())


def make_collision_pieces(mesh: Mesh, cfg: ExportConfig | None = None) -> tuple[Mesh, ...]:
    """Convex pieces (each a closed convex Mesh, frame of ``mesh``) whose union approximates it.

    The pieces are re-hulled (so each is exactly convex with outward faces), sorted by volume
    (largest first), at most ``cfg.max_pieces`` of them, tiny ones dropped.
    """
    cfg = cfg or ExportConfig()
    v = np.asarray(mesh.vertices, float)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4 or len(mesh.faces) == 0:
        raise ValueError(f"make_collision_pieces needs a non-empty (V,3) mesh, got vertices {v.shape}")
    if _is_nearly_convex(mesh, cfg.convex_tolerance):
        return (convex_hull(mesh),)
    try:
        raw = _vhacd(mesh, cfg)
    except Exception:  # V-HACD is a C extension; any failure falls back to the hull
        raw = []
    pieces = []
    for piece in raw:
        if len(piece.vertices) < 4:
            continue
        try:
            hull = convex_hull(piece)
        except Exception:  # degenerate (flat) piece
            continue
        vol = float(hull.to_trimesh().volume)
        if vol > 0:
            pieces.append((vol, hull))
    if not pieces:
        return (convex_hull(mesh),)
    pieces.sort(key=lambda t: -t[0])
    total = sum(vol for vol, _ in pieces)
    kept = [h for vol, h in pieces if vol >= cfg.min_piece_volume_fraction * total][: cfg.max_pieces]
    return tuple(kept)
