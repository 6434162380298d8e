"""Free space seen by other views as evidence against a reading.

A depth reading d on a ray says the surface is at z = d and space in front of it is empty. A point that another
view j sees *in front of its own reading* — it projects into view j at camera depth z_j with the reading there
(min-filtered over a (2·px+1)² window, so that silhouettes do not count) larger than z_j + ``margin`` — is free
space (``seen_in_front``). :func:`contradicted_readings` flags the object rays whose surface point enough other
views saw that way (a flying pixel between a near and a far surface, a misregistered edge).
Reference: space carving (Kutulakos & Seitz, "A theory of shape by space carving", IJCV 2000).
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
