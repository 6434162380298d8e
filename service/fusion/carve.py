"""Free-space evidence of the depth video for points in O (space carving, Kutulakos & Seitz 2000).

A point p_O seen in frame i projects to pixel (u, v) = π(K X_CO(i) p_O) at camera depth z. When the sensor
read a depth D > z + margin there — whatever it saw: the object's front, the table, the background —
the ray crossed p_O before hitting anything, so p_O is empty space, i.e. outside the object. To stay
conservative at silhouettes (pose and mask errors of a few pixels), D is the minimum depth over a
(2r+1)² window, a window with a missing reading (0) is not evidence, and a point must be found empty
in at least ``min_frac`` of the frames in which it is observable.

``free_space_votes`` -> (n_free (P,), n_observed (P,)) over the given frames.

``carve_grid`` applies the same test to the voxels of a fitted SDF that lie inside or near its surface
(S < ``band``): F = the voxels found empty. The returned field is the intersection of the object with the
complement of F, S' = max(S, d_F), d_F the signed distance to F's boundary (positive inside F, from a Euclidean
distance transform, in voxels − ½): the fitted surface where the camera saw nothing through it, F's boundary
where it did. The fit's depth terms can leave matter there: the near-surface band asserts S < 0 up to τ
*behind* every observed point (weight 3000), which past a silhouette edge is outside the object, and the
empty-space term that other views hold against it weighs 1 (docs/fusion.md).
"""

from __future__ import annotations

import numpy as np

from service.sdf.types import SdfGrid
from service.transforms import X_inv, project_to_pixels


def min_depth(depth: np.ndarray, radius_px: int) -> np.ndarray:
    """(H,W) minimum of ``depth`` over a (2r+1)² window; 0 (no reading) anywhere in the window gives 0."""
    import cv2

    D = np.asarray(depth, np.float32)
    if radius_px <= 0:
        return D
    k = 2 * radius_px + 1
    return cv2.erode(D, np.ones((k, k), np.uint8), borderType=cv2.BORDER_REPLICATE)


def free_space_votes(
    points_O: np.ndarray,
    depths: list[np.ndarray],
    X_OC: list[np.ndarray],
    K: np.ndarray,
    *,
    margin: float = 0.01,
    radius_px: int = 3,
) -> tuple[np.ndarray, np.ndarray]:
    """Per point (P,3): number of frames in which it lies in observed empty space, and number of frames
    in which it projects onto a valid reading. ``depths[i]`` (H,W) metres with camera pose ``X_OC[i]`` (4,4)
    in O; K (3,3)."""
    P = np.asarray(points_O, float).reshape(-1, 3)
    n_free = np.zeros(len(P), np.int64)
    n_obs = np.zeros(len(P), np.int64)
    K = np.asarray(K, float)
    for D, X in zip(depths, X_OC):
        Dm = min_depth(D, radius_px)
        H, W = Dm.shape
        X_CO = X_inv(np.asarray(X, float))
        pc = P @ X_CO[:3, :3].T + X_CO[:3, 3]
        z = pc[:, 2]
        u, v, ok = project_to_pixels(pc, K, (H, W), z_min=1e-3)
        d = np.zeros(len(P))
        d[ok] = Dm[v[ok], u[ok]]
        ok &= d > 0
        n_obs += ok
        n_free += ok & (z < d - margin)
    return n_free, n_obs


def _without(grid: SdfGrid, vals: np.ndarray, D: np.ndarray) -> SdfGrid:
    """``grid`` with the voxels D (nx,ny,nz) bool removed from its solid: S' = max(S, d_D), d_D (m) the signed
    distance into D at voxel centres (positive inside D: voxels to the nearest voxel outside it − ½, negative
    outside: ½ − voxels to the nearest voxel of D); ``vals`` the grid's values as float32."""
    from scipy import ndimage

    d_in = ndimage.distance_transform_edt(D)  # voxels to the nearest voxel outside D
    d_out = ndimage.distance_transform_edt(~D)  # voxels to the nearest voxel of D
    d_D = (float(grid.voxel) * np.where(D, d_in - 0.5, 0.5 - d_out)).astype(np.float32)
    return SdfGrid(origin_O=grid.origin_O, voxel=grid.voxel, values=np.maximum(vals, d_D), observed=grid.observed)


def carve_grid(
    grid: SdfGrid,
    depths: list[np.ndarray],
    X_OC: list[np.ndarray],
    K: np.ndarray,
    *,
    margin: float = 0.01,
    radius_px: int = 3,
    min_frac: float = 0.2,
    min_frames: int = 1,
    band: float | None = None,
) -> tuple[SdfGrid, int]:
    """The grid with the observed free space carved out, and the number of voxels found free.

    A voxel with S < ``band`` (default one voxel) is free when it lies in observed empty space
    (``free_space_votes``) in at least ``min_frames`` frames and in at least ``min_frac`` of the frames in which
    it projects onto a reading. ``grid.values`` (nx,ny,nz); frames as for ``free_space_votes``."""
    from service.sdf.grid import grid_points

    vals = np.asarray(grid.values, np.float32)
    band = float(grid.voxel) if band is None else float(band)
    cand = vals.reshape(-1) < band
    if not cand.any() or not len(depths):
        return grid, 0
    P = grid_points(grid.origin_O, grid.voxel, grid.shape).reshape(-1, 3)[cand]
    n_free, n_obs = free_space_votes(P, depths, X_OC, K, margin=margin, radius_px=radius_px)
    free = np.zeros(vals.size, bool)
    free[cand] = (n_free >= max(1, int(min_frames))) & (n_free >= min_frac * n_obs)
    n = int(free.sum())
    if n == 0:
        return grid, 0
    return _without(grid, vals, free.reshape(vals.shape)), n


def open_unsupported(
    grid: SdfGrid, evidence_O: np.ndarray, radius: float, support: float
) -> tuple[SdfGrid, int]:
    """The grid without its thin parts that no evidence point supports, and the number of voxels removed.

    Thin parts are what a morphological opening of the solid {S < 0} by a Euclidean ball of ``radius`` (m, rounded
    to whole voxels, ≥ 1) removes: sheets and spikes thinner than about 2·radius. Of those, a voxel is removed only
    when no evidence point (observed depth surface points and physible points, (K,3) in O) lies within
    ``support`` (m) of its centre; thin walls the camera or a contact saw stay. Same composition as
    ``carve_grid``: S' = max(S, d_D) with d_D the signed distance into the removed set D."""
    from scipy import ndimage
    from scipy.spatial import cKDTree

    from service.sdf.grid import grid_points

    vals = np.asarray(grid.values, np.float32)
    inside = vals < 0
    r = max(1, int(round(float(radius) / float(grid.voxel))))
    k = np.arange(-r, r + 1)
    ball = (k[:, None, None] ** 2 + k[None, :, None] ** 2 + k[None, None, :] ** 2) <= r * r
    opened = ndimage.binary_opening(np.pad(inside, r + 1), ball)[(slice(r + 1, -r - 1),) * 3]
    thin = (inside & ~opened).reshape(-1)
    if not thin.any():
        return grid, 0
    E = np.asarray(evidence_O, float).reshape(-1, 3)
    E = E[np.all(np.isfinite(E), axis=1)]
    P = grid_points(grid.origin_O, grid.voxel, grid.shape).reshape(-1, 3)[thin]
    d = cKDTree(E).query(P, distance_upper_bound=float(support) * (1 + 1e-6))[0] if len(E) else np.full(len(P), np.inf)
    drop = np.zeros(vals.size, bool)
    drop[np.flatnonzero(thin)[~np.isfinite(d)]] = True
    n = int(drop.sum())
    if n == 0:
        return grid, 0
    return _without(grid, vals, drop.reshape(vals.shape)), n
