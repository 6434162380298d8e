"""Procedural object catalogue of the synthetic lab.

Seven everyday objects in the spirit of the Vysics dataset (baking box, bottle, egg, milk carton,
oat-drink carton, styrofoam block, triangular-prism chocolate box) and two non-convex ones
(an L-shaped block and a mug), built with trimesh in metres.

Every object is returned in its *mesh frame* M: origin at the volume centroid of the uniform-density
solid, axes such that the object rests stably on the table with +z up when ``X_WM`` has identity
rotation. ``parts`` are convex pieces whose union is the true solid (one piece for convex objects);
physics uses them as a compound collision shape, so simulated contact geometry equals the exported
mesh up to Bullet's collision margin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh


@dataclass(frozen=True)
class SynthObject:
    kind: str
    mesh: trimesh.Trimesh  # watertight true shape in frame M (origin at the centroid)
    parts: tuple[trimesh.Trimesh, ...]  # convex pieces in M (their union is the solid)
    mass: float  # kg
    rgba: tuple[float, float, float, float]
    convex: bool

    @property
    def extents(self) -> np.ndarray:
        return np.asarray(self.mesh.extents, float)


@dataclass(frozen=True)
class _Kind:
    description: str
    mass: float
    rgba: tuple[float, float, float, float]


KINDS: dict[str, _Kind] = {
    "baking_box": _Kind("cardboard baking-soda box, 9.5 x 6.5 x 12.5 cm", 0.30, (0.93, 0.55, 0.15, 1.0)),
    "bottle": _Kind("plastic bottle, 7 cm diameter, 20 cm tall, domed shoulder", 0.35, (0.20, 0.55, 0.85, 1.0)),
    "egg": _Kind("egg-shaped toy lying on its side, 6.5 cm x 9 cm", 0.10, (0.95, 0.90, 0.75, 1.0)),
    "milk_carton": _Kind("milk carton with gable top, 7 x 7 x 18.5 cm", 0.45, (0.92, 0.92, 0.95, 1.0)),
    "oat_carton": _Kind("oat-drink carton with bevelled edges, 9.5 x 6 x 19.5 cm", 0.35, (0.30, 0.30, 0.35, 1.0)),
    "styrofoam": _Kind("styrofoam block, 20 x 10 x 6 cm (very light)", 0.06, (0.97, 0.97, 0.97, 1.0)),
    "prism": _Kind("triangular-prism chocolate box lying on a face, 21 cm long, 6.5 cm sides", 0.20, (0.90, 0.80, 0.30, 1.0)),
    "l_block": _Kind("non-convex L-shaped wooden block, 14 x 6 x 11 cm", 0.30, (0.65, 0.45, 0.25, 1.0)),
    "mug": _Kind("non-convex open mug (cup without handle), 8.5 cm diameter, 9.5 cm tall", 0.25, (0.75, 0.20, 0.25, 1.0)),
}
OBJECT_KINDS: tuple[str, ...] = tuple(KINDS)


# ----------------------------------------------------------------------------------------- builders
def _box(ex: float, ey: float, ez: float, centre=(0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    m = trimesh.creation.box(extents=(ex, ey, ez))
    m.apply_translation(centre)
    return m


def _hull(points: np.ndarray) -> trimesh.Trimesh:
    return trimesh.convex.convex_hull(np.asarray(points, float))


def _bevel_box(ex: float, ey: float, ez: float, c: float) -> trimesh.Trimesh:
    """Box with all edges chamfered by ``c`` (convex hull of three shrunken boxes)."""
    pts = []
    for dims in ((ex, ey - 2 * c, ez - 2 * c), (ex - 2 * c, ey, ez - 2 * c), (ex - 2 * c, ey - 2 * c, ez)):
        pts.append(_box(*dims).vertices)
    return _hull(np.concatenate(pts))


def _revolve(profile: np.ndarray, sections: int = 40) -> trimesh.Trimesh:
    """Solid of revolution about z from an (n,2) (radius, z) profile running axis -> axis."""
    m = trimesh.creation.revolve(np.asarray(profile, float), sections=sections)
    if m.volume < 0:
        m.invert()
    return m


def _prism(poly_xz: np.ndarray, length_y: float) -> trimesh.Trimesh:
    """Extrude a simple polygon given in the x-z plane (counter-clockwise seen from -y) along y."""
    poly = np.asarray(poly_xz, float)
    n = len(poly)
    tris = _ear_clip(poly)
    h = length_y / 2
    v = np.concatenate([np.c_[poly[:, 0], np.full(n, -h), poly[:, 1]], np.c_[poly[:, 0], np.full(n, h), poly[:, 1]]])
    faces = []
    for a, b, c in tris:
        faces.append((a, b, c))
        faces.append((n + a, n + c, n + b))
    for i in range(n):
        j = (i + 1) % n
        faces.append((i, n + i, n + j))
        faces.append((i, n + j, j))
    m = trimesh.Trimesh(v, np.asarray(faces), process=True)
    trimesh.repair.fix_normals(m)
    return m


def _ear_clip(poly: np.ndarray) -> list[tuple[int, int, int]]:
    """Triangulate a simple counter-clockwise polygon (n,2) by ear clipping (small n)."""
    idx = list(range(len(poly)))
    if _signed_area(poly) < 0:
        idx.reverse()
    out = []
    guard = 0
    while len(idx) > 3 and guard < 1000:
        guard += 1
        for k in range(len(idx)):
            i0, i1, i2 = idx[k - 1], idx[k], idx[(k + 1) % len(idx)]
            a, b, c = poly[i0], poly[i1], poly[i2]
            if _cross(b - a, c - b) <= 1e-12:
                continue
            if any(_in_tri(poly[j], a, b, c) for j in idx if j not in (i0, i1, i2)):
                continue
            out.append((i0, i1, i2))
            idx.pop(k)
            break
    out.append(tuple(idx))
    return out


def _cross(a, b) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def _signed_area(p: np.ndarray) -> float:
    return 0.5 * float(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))


def _in_tri(p, a, b, c) -> bool:
    d1, d2, d3 = _cross(b - a, p - a), _cross(c - b, p - b), _cross(a - c, p - c)
    return d1 >= 0 and d2 >= 0 and d3 >= 0


def _build(kind: str, s: float) -> tuple[trimesh.Trimesh, list[trimesh.Trimesh]]:
    """True solid and its convex parts, at scale ``s``, in an arbitrary frame (rests on +z up)."""
    if kind == "baking_box":
        m = _bevel_box(0.095 * s, 0.065 * s, 0.125 * s, 0.002 * s)
        return m, [m]
    if kind == "bottle":
        R, H, rc = 0.035 * s, 0.20 * s, 0.014 * s
        zs = 0.62 * H
        prof = [(0.0, 0.0), (R - 0.003 * s, 0.0), (R, 0.003 * s), (R, zs)]
        for a in np.linspace(0.0, np.pi / 2, 12)[1:]:
            prof.append((rc + (R - rc) * np.cos(a), zs + (H - zs) * np.sin(a)))
        prof.append((0.0, H))
        m = _revolve(np.asarray(prof), 40)
        return m, [m]
    if kind == "egg":
        a, b = 0.045 * s, 0.0325 * s
        th = np.linspace(0.0, np.pi, 25)
        z = a * np.cos(th)
        r = b * np.sin(th) * (1.0 + 0.10 * np.cos(th))
        prof = np.c_[r, z][::-1]
        prof[0, 0] = prof[-1, 0] = 0.0
        m = _revolve(prof, 40)
        # lie on the side: egg axis along x
        m.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
        return m, [m]
    if kind == "milk_carton":
        ex, ey, ez, roof = 0.07 * s, 0.07 * s, 0.16 * s, 0.025 * s
        base = _box(ex, ey, ez, (0, 0, ez / 2)).vertices
        ridge = np.array([[-ex / 2, 0.0, ez + roof], [ex / 2, 0.0, ez + roof]])
        m = _hull(np.concatenate([base, ridge]))
        return m, [m]
    if kind == "oat_carton":
        m = _bevel_box(0.095 * s, 0.06 * s, 0.195 * s, 0.006 * s)
        return m, [m]
    if kind == "styrofoam":
        m = _box(0.20 * s, 0.10 * s, 0.06 * s)
        return m, [m]
    if kind == "prism":
        side, L = 0.065 * s, 0.21 * s
        h = side * np.sqrt(3) / 2
        m = _prism(np.array([[-side / 2, 0.0], [side / 2, 0.0], [0.0, h]]), L)
        m.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 0, 1]))  # long axis along x
        return m, [m]
    if kind == "l_block":
        lx, w, t, hz, tu = 0.14 * s, 0.06 * s, 0.045 * s, 0.11 * s, 0.045 * s
        poly = np.array([[0, 0], [lx, 0], [lx, t], [tu, t], [tu, hz], [0, hz]])
        m = _prism(poly, w)
        parts = [_box(lx, w, t, (lx / 2, 0, t / 2)), _box(tu, w, hz - t, (tu / 2, 0, t + (hz - t) / 2))]
        return m, parts
    if kind == "mug":
        R, H, wall, bot = 0.0425 * s, 0.095 * s, 0.006 * s, 0.008 * s
        ri = R - wall
        prof = np.array([[0.0, bot], [ri, bot], [ri, H], [R, H], [R, 0.0], [0.0, 0.0]])[::-1]
        m = _revolve(prof, 48)
        n = 12  # wall as a ring of convex staves, plus the base disc
        parts = [_revolve(np.array([[0.0, 0.0], [R, 0.0], [R, bot], [0.0, bot]]), 48)]
        for k in range(n):
            a0, a1 = 2 * np.pi * k / n, 2 * np.pi * (k + 1) / n
            ang = np.linspace(a0, a1, 5)
            ring = np.concatenate([np.c_[rr * np.cos(ang), rr * np.sin(ang)] for rr in (ri, R)])
            pts = np.concatenate([np.c_[ring, np.full(len(ring), zz)] for zz in (bot, H)])
            parts.append(_hull(pts))
        return m, parts
    raise ValueError(f"unknown object kind {kind!r}; known: {', '.join(OBJECT_KINDS)}")


def make_object(kind: str, scale: float = 1.0, mass: float | None = None) -> SynthObject:
    """Build object ``kind`` at ``scale`` in its mesh frame M (origin at the volume centroid)."""
    if kind not in KINDS:
        raise ValueError(f"unknown object kind {kind!r}; known: {', '.join(OBJECT_KINDS)}")
    mesh, parts = _build(kind, float(scale))
    if not mesh.is_watertight or mesh.volume <= 0:
        raise RuntimeError(f"object {kind}: procedural mesh is not a closed solid")
    c = np.asarray(mesh.center_mass, float)
    mesh = mesh.copy()
    mesh.apply_translation(-c)
    parts = tuple(p.copy() for p in parts)
    for p in parts:
        p.apply_translation(-c)
    k = KINDS[kind]
    return SynthObject(kind, mesh, parts, float(mass if mass is not None else k.mass), k.rgba, len(parts) == 1)
