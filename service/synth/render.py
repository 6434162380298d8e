"""Rendering of a simulated session with pybullet's TinyRenderer (RGB, z-buffer, segmentation).

Rendering happens in separate pybullet clients that hold visual-only bodies (no collision shapes),
posed from the physics record, so rendering never disturbs the physics:
- the scene client: object, end-effector sphere, a visual arm (tool rod + forearm cylinders reaching
  back towards the robot base, passing in front of the object like a real arm) and occluders;
- the object-only client: the object alone, giving its unoccluded silhouette (for the hidden fraction
  and for calibrating the occluders).
The table top (a plane, the largest and costliest surface for TinyRenderer) is ray-cast exactly in
numpy once per session and z-composited under the rendered bodies. TinyRenderer only renders the
pixel window that bounds the projected bodies, through the sub-window intrinsics (cx - u0, cy - v0),
which samples exactly the same rays as a full-image render.

Occluders: one box per session, either a vertical *post* (covering the object from one side; the
lateral offset is the free parameter) or a low *wall* in front of it (its top height is the
parameter). At key frames every 0.5 s the parameter is found by bisection so that the occluder alone
hides the requested fraction of the object's unoccluded pixels; between key frames the occluder moves
linearly (slowly). The arm adds to the hidden fraction when it passes in front.

Masks are ``seg == object id``: occluders, the arm and the sphere never count as object pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import hashlib
import os
import tempfile

import cv2
import numpy as np
import pybullet as pb

from service.synth.camera import NEAR, gl_projection_matrix, gl_view_matrix, linearize_depth
from service.synth.objects import SynthObject
from service.synth.sim import EE_RADIUS, TABLE_CENTRE_XY
from service.transforms import mat_to_quat, quat_to_xyzw, so3_exp

ARM_ROD = (0.011, 0.22)  # radius, length of the tool rod above the sphere
ARM_FOREARM = (0.035, 0.42)
LIGHT_DIR = [0.4, -0.6, 1.0]
LIGHT_AMBIENT = 0.55
LIGHT_DIFFUSE = 0.5
TABLE_HALF_SIZE = 0.8  # m, the table top is a 1.6 m square centred on TABLE_CENTRE_XY
TABLE_RGB = (0.50, 0.56, 0.50)
BACKGROUND_RGB = (235, 235, 235)


def object_texture(rgba, rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """Printed-carton-like texture (size,size,3) uint8 RGB: base colour, soft shading, labels, stripes, speckle."""
    base = np.asarray(rgba[:3], float) * 255.0
    img = np.empty((size, size, 3), np.float32)
    img[:] = base
    blot = cv2.resize(rng.standard_normal((6, 6)).astype(np.float32), (size, size), interpolation=cv2.INTER_CUBIC)
    img *= (1.0 + 0.06 * blot)[..., None]
    for _ in range(int(rng.integers(6, 12))):
        x, y = (int(v) for v in rng.integers(0, size, 2))
        w, h = (int(v) for v in rng.integers(size // 16, size // 3, 2))
        col = tuple(float(c) for c in rng.integers(0, 256, 3))
        cv2.rectangle(img, (x, y), (x + w, y + h), col, -1)
    for _ in range(int(rng.integers(2, 5))):
        y = int(rng.integers(0, size))
        col = tuple(float(c) for c in rng.integers(0, 256, 3))
        cv2.line(img, (0, y), (size - 1, y + int(rng.integers(-20, 20))), col, int(rng.integers(1, 5)))
    img += rng.normal(0.0, 6.0, (size, size, 1)).astype(np.float32)
    return np.clip(img, 0, 255).astype(np.uint8)


def object_atlas(rgba, rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """Texture atlas (2*size, 3*size, 3) uint8 RGB: one printed-carton tile per side direction.

    Tile (row, col) = divmod(2*axis + (normal > 0), 3) holds the print of the sides whose normal is
    dominated by +-x, +-y or +-z, so opposite sides of a box and the quadrants around a body of
    revolution carry different prints, as real packaging does. The first tile draws from ``rng`` as
    a single texture always did; the other five come from a generator seeded by that tile's pixels,
    so the rest of the session's random draws do not change.
    """
    first = object_texture(rgba, rng, size)
    sub = np.random.default_rng(np.frombuffer(hashlib.sha256(first.tobytes()).digest()[:8], np.uint64))
    tiles = [first] + [object_texture(rgba, sub, size) for _ in range(5)]
    return np.concatenate([np.concatenate(tiles[r * 3:(r + 1) * 3], axis=1) for r in range(2)], axis=0)


def _visual_mesh(mesh, smooth_deg: float = 35.0) -> tuple[list, list, list, list]:
    """Unshared vertices with auto-smoothed normals (flat across sharp edges) and box-projected UVs.

    Each face takes the two axes orthogonal to its dominant normal axis, mapped into the atlas tile of
    its signed dominant direction (``object_atlas``).
    """
    V = np.asarray(mesh.vertices, float)
    F = np.asarray(mesh.faces, np.int64)
    fn = np.asarray(mesh.face_normals, float)
    vn = np.asarray(mesh.vertex_normals, float)
    verts = V[F].reshape(-1, 3)
    vnf = vn[F].reshape(-1, 3)
    fnf = np.repeat(fn, 3, axis=0)
    cos = np.sum(vnf * fnf, axis=1)
    normals = np.where((cos > np.cos(np.radians(smooth_deg)))[:, None], vnf, fnf)
    idx = np.arange(len(verts))
    span = 1.05 * float(np.max(mesh.extents))
    dom_f = np.argmax(np.abs(fn), axis=1)
    tile_f = 2 * dom_f + (fn[np.arange(len(fn)), dom_f] > 0)
    dom = np.repeat(dom_f, 3)
    row, col = np.divmod(np.repeat(tile_f, 3), 3)
    other = np.array([[1, 2], [0, 2], [0, 1]])[dom]
    centre = np.asarray(mesh.bounds, float).mean(axis=0)
    uv = np.clip(np.take_along_axis(verts - centre, other, axis=1) / span + 0.5, 0.0, 1.0)
    # texture v runs from the image's top row down; tiles are laid out in rows of three
    uv = np.stack([(col + uv[:, 0]) / 3.0, (row + uv[:, 1]) / 2.0], axis=1)
    return verts.tolist(), idx.tolist(), normals.tolist(), uv.tolist()


def _pose_cylinder(a: np.ndarray, b: np.ndarray) -> tuple[list, list]:
    """Position and xyzw orientation of a z-axis cylinder spanning a -> b."""
    d = b - a
    L = np.linalg.norm(d)
    z = d / max(L, 1e-9)
    x = np.cross([0.0, 1.0, 0.0], z)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross([1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z], 1)
    return ((a + b) / 2).tolist(), quat_to_xyzw(mat_to_quat(R))


@dataclass
class Occluder:
    kind: str  # "post" | "wall"
    half_extents: tuple[float, float, float]
    key_t: np.ndarray  # (K,) s
    key_pos: np.ndarray  # (K,3) box centre
    key_yaw: np.ndarray  # (K,)

    def pose(self, t: float) -> tuple[np.ndarray, float]:
        p = np.array([np.interp(t, self.key_t, self.key_pos[:, k]) for k in range(3)])
        return p, float(np.interp(t, self.key_t, self.key_yaw))


def table_image(K: np.ndarray, X_WC: np.ndarray, width: int, height: int, table_h: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Colour (H,W,3) uint8 and z-depth (H,W) of the table top, ray-cast exactly (0 = off the table).

    The table top is the square |x - 0.5|, |y| <= TABLE_HALF_SIZE at z = table_h, a mat with a
    procedural texture (low-frequency blotches plus grain), Lambert-shaded with the renderer's light.
    """
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    rays_C = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    rays_W = rays_C @ X_WC[:3, :3].T
    o = X_WC[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = (table_h - o[2]) / rays_W[..., 2]  # = z-depth since the ray has unit z in C
    hit = o[None, None, :2] + lam[..., None] * rays_W[..., :2]
    cx, cy = TABLE_CENTRE_XY
    on = (lam > 0) & (np.abs(hit[..., 0] - cx) <= TABLE_HALF_SIZE) & (np.abs(hit[..., 1] - cy) <= TABLE_HALF_SIZE)
    depth = np.where(on, lam, 0.0)
    # texture: 2 mm texels over the table
    n_tex = int(2 * TABLE_HALF_SIZE / 0.002)
    coarse = cv2.resize(rng.standard_normal((24, 24)).astype(np.float32), (n_tex, n_tex), interpolation=cv2.INTER_CUBIC)
    mid = cv2.resize(rng.standard_normal((160, 160)).astype(np.float32), (n_tex, n_tex), interpolation=cv2.INTER_LINEAR)
    grain = rng.standard_normal((n_tex, n_tex)).astype(np.float32)
    tex = 0.08 * coarse + 0.05 * mid + 0.03 * grain
    mx = ((hit[..., 0] - (cx - TABLE_HALF_SIZE)) / 0.002).astype(np.float32)
    my = ((hit[..., 1] - (cy - TABLE_HALF_SIZE)) / 0.002).astype(np.float32)
    mx = np.where(on, mx, -1).astype(np.float32)
    my = np.where(on, my, -1).astype(np.float32)
    t = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    l = np.asarray(LIGHT_DIR, float)
    shade = LIGHT_AMBIENT + LIGHT_DIFFUSE * max(l[2] / np.linalg.norm(l), 0.0)
    base = np.array(TABLE_RGB)[None, None, :] * (1.0 + t[..., None]) * shade
    rgb = np.where(on[..., None], np.clip(base * 255.0, 0, 255), BACKGROUND_RGB)
    return rgb.astype(np.uint8), depth


class Renderer:
    """Scene and object-only renderers for one session (table composited by ray casting)."""

    def __init__(self, obj: SynthObject, table_h: float, K: np.ndarray, X_WC: np.ndarray, width: int, height: int, shoulder: np.ndarray, rng: np.random.Generator):
        self.W, self.H = width, height
        self.K = K
        self.X_WC = X_WC
        self.X_CW = np.linalg.inv(X_WC)
        self.view = gl_view_matrix(X_WC)
        self.table_h = table_h
        self.shoulder = np.asarray(shoulder, float)
        self.obj_vertices = np.asarray(obj.mesh.vertices, float)
        self.table_rgb, self.table_depth = table_image(K, X_WC, width, height, table_h, rng)
        verts, idx, normals, uvs = _visual_mesh(obj.mesh)
        self.cid = pb.connect(pb.DIRECT)
        self.oid = pb.connect(pb.DIRECT)
        c = self.cid
        ov = pb.createVisualShape(pb.GEOM_MESH, vertices=verts, indices=idx, normals=normals, uvs=uvs, rgbaColor=[1, 1, 1, 1], physicsClientId=c)
        self.obj = pb.createMultiBody(0, -1, ov, [0, 0, -10], physicsClientId=c)
        with tempfile.TemporaryDirectory(prefix="vysics-synth-tex-") as tdir:
            tex_file = os.path.join(tdir, "object.png")
            cv2.imwrite(tex_file, cv2.cvtColor(object_atlas(obj.rgba, rng), cv2.COLOR_RGB2BGR))
            tex = pb.loadTexture(tex_file, physicsClientId=c)
        pb.changeVisualShape(self.obj, -1, textureUniqueId=tex, physicsClientId=c)
        sv = pb.createVisualShape(pb.GEOM_SPHERE, radius=EE_RADIUS, rgbaColor=[0.75, 0.75, 0.78, 1], physicsClientId=c)
        self.sphere = pb.createMultiBody(0, -1, sv, [0, 0, -10], physicsClientId=c)
        rv = pb.createVisualShape(pb.GEOM_CYLINDER, radius=ARM_ROD[0], length=ARM_ROD[1], rgbaColor=[0.3, 0.3, 0.32, 1], physicsClientId=c)
        self.rod = pb.createMultiBody(0, -1, rv, [0, 0, -10], physicsClientId=c)
        fv = pb.createVisualShape(pb.GEOM_CYLINDER, radius=ARM_FOREARM[0], length=ARM_FOREARM[1], rgbaColor=[0.92, 0.92, 0.92, 1], physicsClientId=c)
        self.forearm = pb.createMultiBody(0, -1, fv, [0, 0, -10], physicsClientId=c)
        self.occluder: Occluder | None = None
        self.occ_body = None
        ov2 = pb.createVisualShape(pb.GEOM_MESH, vertices=verts, indices=idx, normals=normals, physicsClientId=self.oid)
        self.obj_only = pb.createMultiBody(0, -1, ov2, [0, 0, -10], physicsClientId=self.oid)
        self._bounds: list[np.ndarray] = []  # world points bounding what is posed in the scene client
        self._X_WM = np.eye(4)

    def close(self) -> None:
        for c in (self.cid, self.oid):
            try:
                pb.disconnect(physicsClientId=c)
            except Exception:
                pass

    def set_occluder(self, occ: Occluder | None, rgba=(0.35, 0.25, 0.55, 1.0)) -> None:
        self.occluder = occ
        if occ is not None and self.occ_body is None:
            v = pb.createVisualShape(pb.GEOM_BOX, halfExtents=list(occ.half_extents), rgbaColor=list(rgba), physicsClientId=self.cid)
            self.occ_body = pb.createMultiBody(0, -1, v, [0, 0, -10], physicsClientId=self.cid)

    # ------------------------------------------------------------------------------------------
    def _place(self, body: int, pos, orn, cid: int | None = None) -> None:
        pb.resetBasePositionAndOrientation(body, list(map(float, pos)), list(map(float, orn)), physicsClientId=self.cid if cid is None else cid)

    def _object_points(self, X_WM: np.ndarray) -> np.ndarray:
        return self.obj_vertices @ X_WM[:3, :3].T + X_WM[:3, 3]

    def pose_scene(self, X_WM: np.ndarray, p_WE: np.ndarray, t: float, with_arm: bool = True, with_occluder: bool = True) -> None:
        self._X_WM = X_WM
        self._place(self.obj, X_WM[:3, 3], quat_to_xyzw(mat_to_quat(X_WM[:3, :3])))
        bounds = [self._object_points(X_WM)]
        if with_arm:
            e = np.asarray(p_WE, float)
            w = e + np.array([0.0, 0.0, ARM_ROD[1]])
            self._place(self.sphere, e, [0, 0, 0, 1])
            self._place(self.rod, *_pose_cylinder(e, w))
            u = self.shoulder - w
            u /= np.linalg.norm(u)
            f = w + u * ARM_FOREARM[1]
            self._place(self.forearm, *_pose_cylinder(w, f))
            bounds.append(_cube_points([e, w], EE_RADIUS))
            bounds.append(_cube_points([w, f], ARM_FOREARM[0]))
        else:
            for b in (self.sphere, self.rod, self.forearm):
                self._place(b, [0, 0, -10], [0, 0, 0, 1])
        if self.occ_body is not None:
            if self.occluder is None or not with_occluder:
                self._place(self.occ_body, [0, 0, -10], [0, 0, 0, 1])
            else:
                p, yaw = self.occluder.pose(t)
                R = so3_exp(np.array([0.0, 0.0, yaw]))
                self._place(self.occ_body, p, quat_to_xyzw(mat_to_quat(R)))
                corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * np.asarray(self.occluder.half_extents)
                bounds.append(corners @ R.T + p)
        self._bounds = bounds

    def _window(self, pts_W: np.ndarray, margin: int = 3) -> tuple[int, int, int, int] | None:
        """Pixel window (u0, v0, u1, v1) (exclusive ends) covering the projection of pts_W; None if empty."""
        pC = pts_W @ self.X_CW[:3, :3].T + self.X_CW[:3, 3]
        if np.any(pC[:, 2] <= NEAR):
            return 0, 0, self.W, self.H
        uv = pC[:, :2] / pC[:, 2:3] * np.array([self.K[0, 0], self.K[1, 1]]) + self.K[:2, 2]
        u0 = int(np.floor(uv[:, 0].min())) - margin
        v0 = int(np.floor(uv[:, 1].min())) - margin
        u1 = int(np.ceil(uv[:, 0].max())) + margin + 1
        v1 = int(np.ceil(uv[:, 1].max())) + margin + 1
        u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, self.W), min(v1, self.H)
        if u1 - u0 < 1 or v1 - v0 < 1:
            return None
        return u0, v0, u1, v1

    def _render(self, cid: int, win: tuple[int, int, int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        u0, v0, u1, v1 = win
        W, H = u1 - u0, v1 - v0
        Ks = self.K.copy()
        Ks[0, 2] -= u0
        Ks[1, 2] -= v0
        _, _, rgba, depth, seg = pb.getCameraImage(
            W, H, viewMatrix=self.view, projectionMatrix=gl_projection_matrix(Ks, W, H), renderer=pb.ER_TINY_RENDERER,
            lightDirection=LIGHT_DIR, lightAmbientCoeff=LIGHT_AMBIENT, lightDiffuseCoeff=LIGHT_DIFFUSE, lightSpecularCoeff=0.05,
            shadow=0, physicsClientId=cid,
        )
        rgba = np.asarray(rgba, np.uint8).reshape(H, W, 4)
        depth = linearize_depth(np.asarray(depth, np.float64).reshape(H, W))
        seg = np.asarray(seg, np.int32).reshape(H, W)
        return rgba[..., :3], depth, seg

    def render(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rgb (H,W,3) uint8, z-depth (H,W) m, object mask (H,W) bool) of the posed scene."""
        rgb = self.table_rgb.copy()
        depth = self.table_depth.copy()
        mask = np.zeros((self.H, self.W), bool)
        win = self._window(np.concatenate(self._bounds))
        if win is None:
            return rgb, depth, mask
        u0, v0, u1, v1 = win
        r_rgb, r_d, r_seg = self._render(self.cid, win)
        td = depth[v0:v1, u0:u1]
        front = (r_d > 0) & ((td <= 0) | (r_d < td))
        rgb[v0:v1, u0:u1][front] = r_rgb[front]
        td[front] = r_d[front]
        mask[v0:v1, u0:u1] = front & (r_seg == self.obj)
        return rgb, depth, mask

    def object_only_mask(self, X_WM: np.ndarray) -> np.ndarray:
        """Unoccluded silhouette (H,W) bool of the object alone at pose X_WM."""
        self._place(self.obj_only, X_WM[:3, 3], quat_to_xyzw(mat_to_quat(X_WM[:3, :3])), cid=self.oid)
        mask = np.zeros((self.H, self.W), bool)
        win = self._window(self._object_points(X_WM))
        if win is None:
            return mask
        u0, v0, u1, v1 = win
        _, _, seg = self._render(self.oid, win)
        mask[v0:v1, u0:u1] = seg == self.obj_only
        return mask

    def object_window_mask(self, X_WM: np.ndarray) -> tuple[np.ndarray, tuple[int, int, int, int] | None]:
        """Object mask of the posed scene client (object, occluder, arm as posed) inside the object's window."""
        win = self._window(self._object_points(X_WM))
        if win is None:
            return np.zeros((0, 0), bool), None
        _, _, seg = self._render(self.cid, win)
        return seg == self.obj, win


def _cube_points(pts, r: float) -> np.ndarray:
    """Corners of the axis-aligned boxes of half size r around each point (bounds of a swept sphere)."""
    offs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * r
    return np.concatenate([np.asarray(p, float) + offs for p in pts])


def hidden_fraction(visible: np.ndarray, unoccluded: np.ndarray) -> float:
    n = int(unoccluded.sum())
    if n == 0:
        return float("nan")
    return 1.0 - float((visible & unoccluded).sum()) / n


def arm_hidden_fractions(rend: Renderer, X_WM: np.ndarray, p_WE: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N,) fraction of the object hidden by the robot (sphere and arm) alone, per frame (nan: out of view)."""
    out = np.full(len(t), np.nan)
    for i in range(len(t)):
        A = rend.object_only_mask(X_WM[i])
        rend.pose_scene(X_WM[i], p_WE[i], float(t[i]), with_arm=True, with_occluder=False)
        vis, win = rend.object_window_mask(X_WM[i])
        if win is not None:
            u0, v0, u1, v1 = win
            out[i] = hidden_fraction(vis, A[v0:v1, u0:u1])
    return out


def calibrate_occluder(
    rend: Renderer, obj: SynthObject, X_WM: np.ndarray, t: np.ndarray, target: float, rng: np.random.Generator,
    key_dt: float = 0.5, p_WE: np.ndarray | None = None,
) -> Occluder:
    """Place one occluder so that the object is ``target`` hidden at key frames.

    With the robot path ``p_WE`` (N,3), the arm's own hidden fraction h_a (averaged over the key
    interval) is accounted for: the occluder alone aims at 1 - (1 - target) / (1 - h_a), so that
    occluder and arm together hide about ``target``.
    """
    cam = rend.X_WC[:3, 3]
    kind = "post" if rng.random() < 0.5 else "wall"
    side = float(rng.choice([-1.0, 1.0]))
    ext = obj.extents
    rad = 0.5 * float(np.hypot(ext[0], ext[1]))
    top = float(np.max(ext))
    delta = rad + float(rng.uniform(0.06, 0.14))
    if kind == "post":  # wide enough to hide the whole object when centred on it
        he = (1.2 * rad + 0.01, 0.015, 0.5 * (top + 0.06))
    else:
        he = (0.10, 0.015, 0.5 * (2.0 * top + 0.1))
    n = len(t)
    step = max(1, int(round(key_dt / (t[1] - t[0])))) if n > 1 else 1
    keys = list(range(0, n, step))
    if keys[-1] != n - 1:
        keys.append(n - 1)
    key_target = {i: target for i in keys}
    if p_WE is not None:
        h_arm = np.nan_to_num(arm_hidden_fractions(rend, X_WM, p_WE, t), nan=0.0)
        for i in keys:
            h = float(h_arm[max(0, i - step // 2): i + step // 2 + 1].mean())
            key_target[i] = float(np.clip(1.0 - (1.0 - target) / max(1.0 - h, 1e-3), 0.0, target))
    occ = Occluder(kind, he, np.zeros(1), np.zeros((1, 3)), np.zeros(1))
    rend.set_occluder(occ)
    key_pos, key_yaw = [], []
    for i in keys:
        tgt = key_target[i]
        c = X_WM[i, :3, 3]
        u = cam[:2] - c[:2]
        u /= np.linalg.norm(u)
        lat = np.array([-u[1], u[0]])
        yaw = float(np.arctan2(lat[1], lat[0]))
        base = np.array([c[0] + delta * u[0], c[1] + delta * u[1]])
        A = rend.object_only_mask(X_WM[i])

        def pos_of(s: float) -> np.ndarray:
            if kind == "post":
                xy = base + side * s * lat
                return np.array([xy[0], xy[1], rend.table_h + he[2]])
            return np.array([base[0], base[1], rend.table_h + s - he[2]])

        def frac(s: float) -> float:
            occ.key_pos[0] = pos_of(s)
            occ.key_yaw[0] = yaw
            rend.pose_scene(X_WM[i], np.zeros(3), 0.0, with_arm=False)
            vis, win = rend.object_window_mask(X_WM[i])
            if win is None:
                return float("nan")
            u0, v0, u1, v1 = win
            return hidden_fraction(vis, A[v0:v1, u0:u1])

        if kind == "post":  # hidden fraction decreases with the lateral offset s
            lo, hi = 0.0, he[0] + rad + 0.05
            for _ in range(12):
                mid = 0.5 * (lo + hi)
                f = frac(mid)
                if np.isnan(f) or f > tgt:
                    lo = mid
                else:
                    hi = mid
        else:  # hidden fraction increases with the wall's top height s
            lo, hi = 0.0, 2.0 * he[2]
            for _ in range(12):
                mid = 0.5 * (lo + hi)
                f = frac(mid)
                if np.isnan(f) or f < tgt:
                    lo = mid
                else:
                    hi = mid
        key_pos.append(pos_of(0.5 * (lo + hi)))
        key_yaw.append(yaw)
    key_yaw = np.unwrap(np.asarray(key_yaw))
    final = Occluder(kind, he, t[keys], np.asarray(key_pos), key_yaw)
    rend.set_occluder(final)
    return final
