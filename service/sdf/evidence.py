"""Depth of the near-surface band behind each object ray, limited by what other views saw (evidence band).

A depth reading d on a ray says the surface is at z = d and space in front of it is empty; it says nothing of
how far the object extends behind it. BundleSDF's band claims a fixed τ behind every reading as inside
(S = d − z down to z = d + τ), which is wrong behind a wall thinner than τ (a mug's 6 mm) or a wedge (a prism's
ridge): the band then reaches into air that other views of the turning object saw.

Here the thickness of the object behind object ray r is measured by the other views: walking behind the reading,
z_k = d + k·h (k = 1, 2, …, h = ``step``, up to ``trunc``), the first sample p_k that some view j sees *in front of
its own reading* — p_k projects into view j at camera depth z_j with the reading there (min-filtered over a
(2·px+1)² window, so that silhouettes do not count) larger than z_j + ``margin`` — is free space beyond the far
side of the object. The thickness of r is then ℓ_r = max(z_k − h/2 − margin − d, 0) (the surface j saw lies about
``margin`` before the first such sample), else ∞ where no view contradicts the band within ``trunc``.
:func:`service.sdf.fit_sdf` (``band_back = ℓ``) then supervises behind the reading only down to ℓ_r, with the
distance to the nearer of the two sides, S = −min(z − d, ℓ_r − (z − d)) (a wall of thickness ℓ_r), and keeps
BundleSDF's band (S = d − z down to τ) where ℓ_r = ∞: behind a solid several centimetres thick nothing changes,
behind a thin wall or a ridge seen from both sides the band no longer reaches into the air on the other side.
Reference: space carving (Kutulakos & Seitz, "A theory of shape by space carving", IJCV 2000) applied to the
band of BundleSDF (Wen et al., CVPR 2023).
"""

from __future__ import annotations

from typing import Iterable, Sequence

import numpy as np

from service.sdf.types import RaySet
from service.transforms import project_to_pixels


def min_filter_depth(depth: np.ndarray, px: int) -> np.ndarray:
    """(H,W) float32: ``depth`` (m, 0 = no reading) with holes set far (1000 m) and min-filtered over a
    (2·px+1)² window, so that a point near a silhouette or a few pixels off is not taken as seen past."""
    import cv2

    d = np.where(depth > 0, depth, 1e3).astype(np.float32)
    if px > 0:
        k = 2 * px + 1
        d = cv2.erode(d, np.ones((k, k), np.uint8))  # erosion = min filter
    return d


def seen_in_front(P: np.ndarray, views: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]], margin: float,
                  count: int = 1) -> np.ndarray:
    """(P,) bool: at least ``count`` of ``views`` see the point (P,3) in front of their own reading by more than
    ``margin`` — the camera looked past it, so it is empty space. ``views``: (K (3,3), X_CO (4,4) pose of the
    points' frame in that camera, depth (H,W) already passed through :func:`min_filter_depth`)."""
    n = np.zeros(len(P), np.int32)
    for K, X_CO, dm in views:
        todo = np.nonzero(n < count)[0]
        Q = P[todo] @ X_CO[:3, :3].T + X_CO[:3, 3]
        z = Q[:, 2]
        u, v, ins = project_to_pixels(Q, K, dm.shape)
        zo = dm[v[ins], u[ins]]
        idx = todo[ins]
        n[idx[(zo < 1e2) & (zo > z[ins] + margin)]] += 1
    return n >= count


def _filtered(views, px: int) -> list:
    return [(K, X_CO, min_filter_depth(np.asarray(depth), px)) for K, X_CO, depth in views]


def contradicted_readings(
    rays: RaySet,
    views: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]],
    *,
    margin: float = 0.003,
    px: int = 2,
    min_views: int = 1,
) -> np.ndarray:
    """(R,) bool: object rays whose surface point at least ``min_views`` views of ``views`` saw in front of their
    own reading by more than ``margin`` (depth min-filtered over (2·px+1)² pixels) — a reading that other views
    contradict (a flying pixel between a near and a far surface, a misregistered edge); False for free rays.
    ``min_views`` > 1 tolerates a view whose pose is off."""
    out = np.zeros(len(rays), bool)
    obj = np.nonzero(rays.depth > 0)[0]
    if len(obj) and len(views):
        out[obj] = seen_in_front(rays.surface_points_O, _filtered(views, px), margin, min_views)  # surface_points_O: the object rays, in order
    return out


def evidence_band(
    rays: RaySet,
    views: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]],
    trunc: float,
    *,
    margin: float = 0.002,
    step: float = 0.001,
    px: int = 2,
) -> np.ndarray:
    """Thickness ℓ (R,) of the object behind each ray of ``rays``, metres of camera depth (see module docstring);
    ∞ for free rays (depth 0) and where no view contradicts the band within ``trunc``.

    ``views``: (K (3,3), X_CO (4,4) pose of O in that camera, depth (H,W) m, 0 = no reading) of the frames whose
    free space limits the band (typically the frames the rays come from)."""
    if trunc <= 0 or step <= 0 or margin < 0:
        raise ValueError(f"evidence_band: trunc and step must be > 0 and margin >= 0, got {trunc}, {step}, {margin}")
    R = len(rays)
    out = np.full(R, np.inf)
    obj = np.nonzero(rays.depth > 0)[0]
    if len(obj) == 0 or len(views) == 0:
        return out
    n = int(np.ceil(trunc / step))
    dz = step * np.arange(1, n + 1)  # (n,)
    o, dvec, d = rays.origins_O[obj], rays.dirs_O[obj], rays.depth[obj]
    P = o[:, None, :] + (d[:, None] + dz[None, :])[..., None] * dvec[:, None, :]  # (M,n,3)
    P = P.reshape(-1, 3)
    hit = seen_in_front(P, _filtered(views, px), margin)
    hit = hit.reshape(len(obj), n)
    first = np.where(hit.any(1), hit.argmax(1), n)  # index of the first contradicted sample, n = none
    out[obj] = np.where(first < n, np.maximum(dz[np.minimum(first, n - 1)] - 0.5 * step - margin, 0.0), np.inf)
    return out
