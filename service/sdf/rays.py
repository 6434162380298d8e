"""Rays of one masked depth frame, expressed in O (input of :func:`service.sdf.fit_sdf`).

Pixel (u,v) with depth d back-projects to p_C = d · K⁻¹[u,v,1]ᵀ (docs/conventions.md); in O the ray is
o_O + z · dir_O with o_O = X_OC translation and dir_O = R_OC K⁻¹[u,v,1]ᵀ. Object rays: pixels in the mask with a
depth reading (optionally only where ``keep`` is True). Free rays: pixels in the ring obtained by dilating the
mask by ``ring_px`` (BundleSDF dilates by 60 px); their reading, if any, bounds the known-empty segment.
"""

from __future__ import annotations

import numpy as np

from service.sdf.types import RaySet


def rays_from_frame(
    depth: np.ndarray,
    mask: np.ndarray,
    K: np.ndarray,
    X_OC: np.ndarray,
    *,
    stride: int = 4,
    ring_px: int = 30,
    max_object_rays: int = 3000,
    max_free_rays: int = 2000,
    keep: np.ndarray | None = None,
    weight: float = 1.0,
    rng: np.random.Generator | None = None,
    back: np.ndarray | None = None,
) -> RaySet:
    """RaySet of one frame. depth (H,W) m (0 = none), mask (H,W) bool, K (3,3), X_OC (4,4). ``back`` (H,W) m,
    optional: the band depth behind the reading of each pixel's object ray (``RaySet.back``; nan: the fit's)."""
    import cv2

    rng = rng or np.random.default_rng(0)
    H, W = depth.shape
    if mask.shape != (H, W):
        raise ValueError(f"mask shape {mask.shape} differs from depth shape {(H, W)}")
    grid = np.zeros((H, W), bool)
    grid[::stride, ::stride] = True
    m = mask.astype(bool)
    obj = m & (depth > 0) & grid
    if keep is not None:
        obj &= keep
    k = 2 * ring_px + 1
    dil = cv2.dilate(m.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))) > 0
    free = dil & ~m & grid

    def pick(sel: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        v, u = np.nonzero(sel)
        if len(u) > n:
            i = rng.choice(len(u), n, replace=False)
            u, v = u[i], v[i]
        return u, v

    uo, vo = pick(obj, max_object_rays)
    uf, vf = pick(free, max_free_rays)
    u = np.concatenate([uo, uf]).astype(float)
    v = np.concatenate([vo, vf]).astype(float)
    Kinv = np.linalg.inv(K)
    dirs_C = np.stack([u, v, np.ones_like(u)], 1) @ Kinv.T
    dirs_O = dirs_C @ X_OC[:3, :3].T
    orig = np.broadcast_to(X_OC[:3, 3], dirs_O.shape).copy()
    d_all = depth[v.astype(int), u.astype(int)].astype(float)
    n_o = len(uo)
    dep = np.zeros(len(u))
    dep[:n_o] = d_all[:n_o]
    free_until = np.full(len(u), np.inf)
    fd = d_all[n_o:]
    free_until[n_o:] = np.where(fd > 0, fd, np.inf)
    bk = None
    if back is not None:
        bk = np.full(len(u), np.nan)
        bk[:n_o] = back[vo, uo]
    return RaySet(orig, dirs_O, dep, free_until, np.full(len(u), float(weight)), back=bk)
