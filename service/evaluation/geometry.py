"""Geometry metrics: surface sampling, chamfer distance, ICP alignment and volumetric IoU.

Chamfer (method-notes §8.1): with A, B (n,3) surface samples (area-weighted, 2000 per mesh; a
multi-component estimate gets 10 points per small component and the rest on the largest),

    CD(A, B) = ½ ( mean_{a∈A} min_{b∈B} ‖a − b‖ + mean_{b∈B} min_{a∈A} ‖a − b‖ )      [m]

with nearest neighbours from KD-trees.

Alignment (evaluation only): point-to-point ICP (Besl & McKay 1992) of the ground-truth samples onto the
estimate's samples, correspondences closer than ``max_corr`` (0.02 m), closed-form Kabsch update,
started from a given pose.

Volumetric IoU (§8.2 [REC]): both meshes are voxelized on one grid over the union of their bounding
boxes (pitch ``max(pitch, extent / max_res)``); a voxel centre is inside a mesh when at least two of
the three axis-aligned rays through it cross the surface an odd number of times (parity by scan
lines, which also tolerates small holes in a non-watertight mesh); IoU = |A∩B| / |A∪B|.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from service.mesh import Mesh
from service.transforms import make_X, transform_points


def _tm(mesh):
    import trimesh

    if isinstance(mesh, trimesh.Trimesh):
        return mesh
    return trimesh.Trimesh(np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64), process=False)


def _area_sample(v: np.ndarray, f: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if n <= 0 or area.sum() <= 0:
        return np.zeros((0, 3))
    idx = rng.choice(len(f), size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    a, b, c = 1 - s, s * (1 - r2), s * r2
    t = tri[idx]
    return a[:, None] * t[:, 0] + b[:, None] * t[:, 1] + c[:, None] * t[:, 2]


def sample_surface(mesh: Mesh, n: int = 2000, seed: int = 0, split_components: bool = False) -> np.ndarray:
    """Area-weighted surface samples (n,3). With ``split_components``, every connected component but the
    largest gets 10 points and the largest the rest (method-notes §8.1)."""
    rng = np.random.default_rng(seed)
    v = np.asarray(mesh.vertices, float)
    f = np.asarray(mesh.faces, np.int64)
    if len(f) == 0:
        return np.zeros((0, 3))
    if split_components:
        import trimesh

        labels = trimesh.graph.connected_component_labels(trimesh.graph.face_adjacency(f), node_count=len(f))
        comps = [np.flatnonzero(labels == k) for k in np.unique(labels)]
        if len(comps) > 1:
            tri = v[f]
            areas = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
            comps.sort(key=lambda c: -areas[c].sum())
            per_small = 10 if 10 * (len(comps) - 1) < n // 2 else max(1, n // (2 * len(comps)))
            counts = [n - per_small * (len(comps) - 1)] + [per_small] * (len(comps) - 1)
            return np.concatenate([_area_sample(v, f[c], k, rng) for c, k in zip(comps, counts)])
    return _area_sample(v, f, n, rng)


def chamfer(A: np.ndarray, B: np.ndarray) -> float:
    """Two-way mean chamfer distance (m) between point sets A (n,3) and B (m,3)."""
    if len(A) == 0 or len(B) == 0:
        raise ValueError("chamfer distance needs two non-empty point sets")
    dab = cKDTree(B).query(A)[0]
    dba = cKDTree(A).query(B)[0]
    return float(0.5 * (dab.mean() + dba.mean()))


def chamfer_naive(A: np.ndarray, B: np.ndarray) -> float:
    """Slow O(nm) reference of :func:`chamfer`."""
    D = np.linalg.norm(A[:, None, :] - B[None, :, :], axis=-1)
    return float(0.5 * (D.min(1).mean() + D.min(0).mean()))


def kabsch(P: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """Rigid X (4,4) minimising Σ‖X p_i − q_i‖² for paired points P, Q (n,3)."""
    cp, cq = P.mean(0), Q.mean(0)
    H = (P - cp).T @ (Q - cq)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return make_X(R, cq - R @ cp)


@dataclass(frozen=True)
class ICPResult:
    X: np.ndarray  # (4,4) pose mapping the source points onto the target
    rmse: float  # m, over inlier correspondences
    fitness: float  # fraction of source points with a correspondence within max_corr
    iterations: int


def icp(source: np.ndarray, target: np.ndarray, X_init: np.ndarray | None = None, max_corr: float = 0.02,
        max_iter: int = 2000, tol: float = 1e-7) -> ICPResult:
    """Point-to-point ICP of ``source`` (n,3) onto ``target`` (m,3), starting at ``X_init``."""
    X = np.eye(4) if X_init is None else np.asarray(X_init, float).copy()
    tree = cKDTree(target)
    prev = np.inf
    it = 0
    rmse, fit = np.inf, 0.0
    for it in range(1, max_iter + 1):
        P = transform_points(X, source)
        d, j = tree.query(P, distance_upper_bound=max_corr)
        ok = np.isfinite(d)
        fit = float(ok.mean())
        if ok.sum() < 3:
            break
        rmse = float(np.sqrt(np.mean(d[ok] ** 2)))
        X = kabsch(P[ok], target[j[ok]]) @ X
        if abs(prev - rmse) < tol:
            break
        prev = rmse
    P = transform_points(X, source)
    d, _ = tree.query(P, distance_upper_bound=max_corr)
    ok = np.isfinite(d)
    if ok.any():
        rmse, fit = float(np.sqrt(np.mean(d[ok] ** 2))), float(ok.mean())
    return ICPResult(X, rmse, fit, it)


# ------------------------------------------------------------------------------------ voxelization
def _parity_axis(tri: np.ndarray, origin: np.ndarray, pitch: float, shape: tuple[int, int, int], axis: int) -> np.ndarray:
    """Inside-parity of voxel centres along rays parallel to ``axis`` (bool grid of ``shape``)."""
    b, c = [a for a in range(3) if a != axis]
    nb, nc, na = shape[b], shape[c], shape[axis]
    U = tri[:, :, b]
    V = tri[:, :, c]
    # columns covered by each triangle's bounding box in (b, c)
    i0 = np.clip(np.ceil((U.min(1) - origin[b]) / pitch).astype(int), 0, nb)
    i1 = np.clip(np.floor((U.max(1) - origin[b]) / pitch).astype(int), -1, nb - 1)
    j0 = np.clip(np.ceil((V.min(1) - origin[c]) / pitch).astype(int), 0, nc)
    j1 = np.clip(np.floor((V.max(1) - origin[c]) / pitch).astype(int), -1, nc - 1)
    ni = np.maximum(i1 - i0 + 1, 0)
    nj = np.maximum(j1 - j0 + 1, 0)
    cnt = ni * nj
    flips = np.zeros((nb, nc, na + 1), np.int32)
    total = int(cnt.sum())
    if total == 0:
        return np.zeros(shape, bool)
    chunk = 4_000_000
    t_all = np.repeat(np.arange(len(tri)), cnt)
    start = np.repeat(np.cumsum(cnt) - cnt, cnt)
    for s0 in range(0, total, chunk):
        t = t_all[s0 : s0 + chunk]
        local = np.arange(s0, min(s0 + chunk, total)) - start[s0 : s0 + chunk]
        ii = i0[t] + local // nj[t]
        jj = j0[t] + local % nj[t]
        pu = origin[b] + ii * pitch
        pv = origin[c] + jj * pitch
        u0, u1, u2 = U[t, 0], U[t, 1], U[t, 2]
        v0, v1, v2 = V[t, 0], V[t, 1], V[t, 2]
        det = (u1 - u0) * (v2 - v0) - (u2 - u0) * (v1 - v0)
        good = np.abs(det) > 1e-18
        det = np.where(good, det, 1.0)
        l1 = ((pu - u0) * (v2 - v0) - (u2 - u0) * (pv - v0)) / det
        l2 = ((u1 - u0) * (pv - v0) - (pu - u0) * (v1 - v0)) / det
        l0 = 1 - l1 - l2
        hit = good & (l0 >= 0) & (l1 >= 0) & (l2 >= 0)
        w = l0 * tri[t, 0, axis] + l1 * tri[t, 1, axis] + l2 * tri[t, 2, axis]
        k = np.clip(np.ceil((w - origin[axis]) / pitch).astype(int), 0, na)
        np.add.at(flips, (ii[hit], jj[hit], k[hit]), 1)
    par = (np.cumsum(flips, axis=2)[:, :, :na] % 2).astype(bool)  # (nb, nc, na)
    # back to (x, y, z) order
    order = [0, 0, 0]
    order[b], order[c], order[axis] = 0, 1, 2
    return np.transpose(par, order)


def occupancy(mesh: Mesh, origin: np.ndarray, pitch: float, shape: tuple[int, int, int]) -> np.ndarray:
    """Bool grid (shape) of voxel centres ``origin + pitch * (i, j, k)`` inside ``mesh`` (2-of-3 ray vote)."""
    v = np.asarray(mesh.vertices, float)
    f = np.asarray(mesh.faces, np.int64)
    tri = v[f]
    votes = sum(_parity_axis(tri, np.asarray(origin, float), pitch, shape, a).astype(np.int8) for a in range(3))
    return votes >= 2


@dataclass(frozen=True)
class VoxelIoU:
    iou: float
    volume_a: float  # m^3 (voxel count × pitch³)
    volume_b: float
    pitch: float  # m


def voxel_iou(a: Mesh, b: Mesh, pitch: float = 0.002, max_res: int = 128) -> VoxelIoU:
    """Volumetric IoU of two meshes on a common grid (see module docstring)."""
    va, vb = np.asarray(a.vertices, float), np.asarray(b.vertices, float)
    lo = np.minimum(va.min(0), vb.min(0))
    hi = np.maximum(va.max(0), vb.max(0))
    pitch = float(max(pitch, (hi - lo).max() / max_res))
    # a tiny irrational shift keeps rays off mesh edges and vertices that sit on round coordinates
    origin = lo - pitch + pitch * np.array([0.0137, 0.0291, 0.0173]) * np.sqrt(2)
    shape = tuple(int(x) for x in np.ceil((hi - origin) / pitch) + 2)
    A = occupancy(a, origin, pitch, shape)
    B = occupancy(b, origin, pitch, shape)
    union = int((A | B).sum())
    inter = int((A & B).sum())
    return VoxelIoU(inter / union if union else float("nan"), A.sum() * pitch**3, B.sum() * pitch**3, pitch)
