"""Small analytic scenes for the fusion tests: a box seen from one side, with contacts on the others."""

from __future__ import annotations

import numpy as np
import trimesh

from service.mesh import Mesh
from service.sdf.types import RaySet

HALF = np.array([0.04, 0.03, 0.02])  # box half extents, m


def box_mesh(half=HALF) -> Mesh:
    return Mesh.from_trimesh(trimesh.creation.box(tuple(2 * np.asarray(half))))


def box_sdf(points: np.ndarray, half=HALF) -> np.ndarray:
    """Exact signed distance of the box (P,3) -> (P,)."""
    q = np.abs(points) - half
    return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(1), 0)


def look_at(eye: np.ndarray, target=np.zeros(3)) -> np.ndarray:
    """X_OC (4,4) of an OpenCV camera at ``eye`` looking at ``target`` (world up = +z)."""
    z = target - eye
    z = z / np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    if np.linalg.norm(x) < 1e-6:
        x = np.array([1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    X = np.eye(4)
    X[:3, :3] = np.stack([x, y, z], 1)
    X[:3, 3] = eye
    return X


def ray_box(o: np.ndarray, d: np.ndarray, half=HALF) -> np.ndarray:
    """Ray parameter of the first hit of o + t d with the box, inf when missed. (R,3),(R,3) -> (R,)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / np.where(np.abs(d) < 1e-12, 1e-12, d)
        t1, t2 = (-half - o) * inv, (half - o) * inv
    tin = np.minimum(t1, t2).max(1)
    tout = np.maximum(t1, t2).min(1)
    return np.where((tout >= tin) & (tin > 0), tin, np.inf)


def camera_rays(eyes, n_px: int = 40, fov: float = 0.5, ring: float = 0.012) -> RaySet:
    """Object rays (hit the box) and free rays (miss it, passing within ``ring`` of it) of pinhole
    cameras at ``eyes`` (K,3) looking at the origin; n_px × n_px rays each over ``fov`` rad."""
    parts = []
    for eye in np.asarray(eyes, float):
        X = look_at(eye)
        s = np.tan(fov / 2)
        u = np.linspace(-s, s, n_px)
        uu, vv = np.meshgrid(u, u)
        dirs_C = np.stack([uu.ravel(), vv.ravel(), np.ones(uu.size)], 1)  # unit camera-z
        dirs = dirs_C @ X[:3, :3].T
        o = np.repeat(eye[None], len(dirs), 0)
        t = ray_box(o, dirs)
        hit = np.isfinite(t)
        # free rays: misses whose closest approach to the box is within the ring
        ts = np.linspace(0.0, 2 * np.linalg.norm(eye), 200)
        dmin = np.min([box_sdf(o + tt * dirs) for tt in ts], axis=0)
        free = ~hit & (dmin < ring)
        sel = hit | free
        parts.append(
            RaySet(
                origins_O=o[sel],
                dirs_O=dirs[sel],
                depth=np.where(hit, t, 0.0)[sel],  # camera-z depth equals t (dirs have unit camera-z)
                free_until=np.full(int(sel.sum()), np.inf),
                weight=np.ones(int(sel.sum())),
            )
        )
    return RaySet.concatenate(parts)


# cameras with |y| < half_y, x > half_x, z > half_z see only the +x and +z faces
EYES_ONE_SIDE = np.array([[0.40, 0.02, 0.40], [0.45, -0.02, 0.25], [0.30, 0.0, 0.50], [0.50, 0.01, 0.15]])


def face_points(n: int, axis: int, sign: float, rng: np.random.Generator, half=HALF, margin=0.1):
    """n points on the box face {x_axis = sign·half_axis} (inner (1 − margin) part) and its normal."""
    pts = (rng.random((n, 3)) * 2 - 1) * half * (1 - margin)
    pts[:, axis] = sign * half[axis]
    nrm = np.zeros((n, 3))
    nrm[:, axis] = sign
    return pts, nrm


def hidden_contacts(rng: np.random.Generator, n_bottom=40, n_back=20, n_side=10):
    """Physible points on the faces the cameras never see: bottom (−z), back (−x), side (−y)."""
    a = face_points(n_bottom, 2, -1.0, rng)
    b = face_points(n_back, 0, -1.0, rng)
    c = face_points(n_side, 1, -1.0, rng)
    return np.concatenate([a[0], b[0], c[0]]), np.concatenate([a[1], b[1], c[1]])


def chamfer(mesh: Mesh, ref: Mesh, n: int = 4000, seed: int = 0) -> float:
    """Two-way mean surface distance (m) between area samples of two meshes."""
    a = mesh.to_trimesh()
    b = ref.to_trimesh()
    pa = trimesh.sample.sample_surface(a, n, seed=seed)[0]
    pb = trimesh.sample.sample_surface(b, n, seed=seed + 1)[0]
    from scipy.spatial import cKDTree

    return 0.5 * (cKDTree(pb).query(pa)[0].mean() + cKDTree(pa).query(pb)[0].mean())


def write_box_session(root, n_frames: int = 6, width: int = 96, height: int = 72, seed: int = 0):
    """A tiny on-disk session of the box sliding on a table, seen by one camera from the +x/+z side.

    Returns (Session, X_WO (N,4,4)). O is the box centre; the table is z = 0 in W."""
    import cv2
    from pathlib import Path

    from service.session.types import Friction, Session

    root = Path(root)
    (root / "depth").mkdir(parents=True, exist_ok=True)
    (root / "masks").mkdir(parents=True, exist_ok=True)
    f = 0.94 * width  # the same field of view at any image size
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])
    X_WC = look_at(np.array([0.42, 0.01, 0.40]), target=np.array([0.0, 0.0, HALF[2]]))
    X_WO = np.repeat(np.eye(4)[None], n_frames, 0)
    X_WO[:, 0, 3] = np.linspace(-0.01, 0.01, n_frames)
    X_WO[:, 1, 3] = np.linspace(0.0, 0.005, n_frames)
    X_WO[:, 2, 3] = HALF[2]
    uu, vv = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    dirs_C = np.stack([uu.ravel(), vv.ravel(), np.ones(uu.size)], 1) @ np.linalg.inv(K).T
    depth_files, mask_files = [], []
    for i in range(n_frames):
        X_OC = np.linalg.inv(X_WO[i]) @ X_WC
        d_O = dirs_C @ X_OC[:3, :3].T
        o_O = np.repeat(X_OC[None, :3, 3], len(d_O), 0)
        t = ray_box(o_O, d_O).reshape(height, width)
        hit = np.isfinite(t)
        depth_mm = np.where(hit, np.round(t * 1000.0), 0).astype(np.uint16)
        dp, mp = root / "depth" / f"{i:06d}.png", root / "masks" / f"{i:06d}.png"
        cv2.imwrite(str(dp), depth_mm)
        cv2.imwrite(str(mp), (hit * 255).astype(np.uint8))
        depth_files.append(dp)
        mask_files.append(mp)
    t = np.arange(n_frames) / 30.0
    session = Session(
        name="box", root=root, sha256="0" * 64, frame_times=t, K=K, X_WC=X_WC, depth_scale=0.001,
        width=width, height=height, rgb_files=tuple(depth_files), depth_files=tuple(depth_files),
        mask_files=tuple(mask_files), robot_t=t, robot_p_WE=np.tile([0.3, 0.0, 0.3], (n_frames, 1)), robot_cmd_WE=None,
        p_WE=np.tile([0.3, 0.0, 0.3], (n_frames, 1)), cmd_WE=None, ee_radius=0.01, table_height=0.0,
        table_height_detected=False, friction=Friction(), mass=None, has_ground_truth=False,
    )
    return session, X_WO
