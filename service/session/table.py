"""Table-plane detection from depth frames (used when ``table.height`` is null).

Points: for a few frames, every valid depth pixel outside the dilated object mask is back-projected,
p_C = d K^-1 [u, v, 1]^T, and mapped to the world, p_W = X_WC p_C. The object's own points give an upper
bound for the table: z_max = (2nd percentile of the object's z) + 2 cm.

RANSAC (hypotheses scored on a random subset of the points): planes n.p = c through 3 random points are kept
only when near-horizontal (angle(n, z_W) <= ``max_tilt_deg``); points above z_max were removed beforehand.
Each hypothesis is scored by its inliers (|n.p - c| <= ``inlier_m``) and its height under the object.
Hypotheses within ``surface_gap_m`` in height form one surface (its best hypothesis stands for it); of the
surfaces with at least ``min_support_ratio`` of the best surface's support, the highest wins: the object
rests on the table, so a floor or a lower bench seen past the table edge is not taken for it, however
large. It is refined by total least squares (SVD of the centred inliers),
twice, with the inlier band shrunk to 3 robust sigmas (MAD), not below ``min_band_m``.
The table height is the refined plane's z at the object's centroid (x, y) (or at the inliers' centroid
when there are no object points). No plane with at least ``min_inliers`` points -> error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TablePlaneConfig:
    max_points: int = 40_000  # background points kept for the fit (over all frames)
    ransac_points: int = 4_000  # points on which RANSAC hypotheses are scored
    iterations: int = 300
    inlier_m: float = 0.01
    min_band_m: float = 0.002
    max_tilt_deg: float = 10.0
    min_inliers: int = 200
    min_inlier_fraction: float = 0.05
    surface_gap_m: float = 0.03  # hypotheses closer than this in height are the same surface
    min_support_ratio: float = 0.1  # a surface needs this fraction of the best surface's inliers
    mask_dilate_px: int = 3
    seed: int = 0


@dataclass(frozen=True)
class TablePlane:
    height: float  # z of the table at the object's (x, y), m
    normal_W: np.ndarray  # (3,) unit, z >= 0
    offset: float  # n . p = offset
    n_inliers: int
    n_points: int
    rms_m: float  # residual RMS of the inliers


def back_project(
    depth_m: np.ndarray, K: np.ndarray, X_WC: np.ndarray, sel: np.ndarray, max_points: int | None = None, rng=None
) -> np.ndarray:
    """World points (P,3) of the pixels selected by the boolean ``sel`` (H,W) with depth > 0.

    With ``max_points``, a uniform random subset of at most that many pixels is back-projected.
    """
    v, u = np.nonzero(sel & (depth_m > 0))
    if max_points is not None and len(u) > max_points:
        rng = rng if rng is not None else np.random.default_rng(0)
        k = rng.choice(len(u), max_points, replace=False)
        v, u = v[k], u[k]
    z = depth_m[v, u].astype(float)
    y = (v - K[1, 2]) / K[1, 1] * z
    x = (u - K[0, 2]) / K[0, 0] * z - K[0, 1] / K[0, 0] * y
    p_C = np.stack([x, y, z], axis=1)
    return p_C @ X_WC[:3, :3].T + X_WC[:3, 3]


def detect_table_plane(
    depths: list[np.ndarray],
    masks: list[np.ndarray],
    K: np.ndarray,
    X_WC: np.ndarray,
    cfg: TablePlaneConfig = TablePlaneConfig(),
) -> TablePlane | None:
    """Fit the table plane to depth frames (metres, (H,W)) and object masks (bool, (H,W)); None if absent."""
    import cv2

    rng = np.random.default_rng(cfg.seed)
    kernel = np.ones((2 * cfg.mask_dilate_px + 1,) * 2, np.uint8)
    bg_pts, obj_pts = [], []
    per_frame = max(1, cfg.max_points // max(1, len(depths)))
    for d, m in zip(depths, masks):
        m8 = m.astype(np.uint8)
        dil = cv2.dilate(m8, kernel) > 0 if cfg.mask_dilate_px > 0 else m
        bg_pts.append(back_project(d, K, X_WC, ~dil, per_frame, rng))
        obj_pts.append(back_project(d, K, X_WC, m, per_frame, rng))
    P = np.concatenate(bg_pts) if bg_pts else np.zeros((0, 3))
    O = np.concatenate(obj_pts) if obj_pts else np.zeros((0, 3))
    z_max = np.inf
    if len(O) >= 10:
        z_max = float(np.percentile(O[:, 2], 2)) + 0.02
        P = P[P[:, 2] <= z_max + cfg.inlier_m]
    if len(P) > cfg.max_points:
        P = P[rng.choice(len(P), cfg.max_points, replace=False)]
    n_pts = len(P)
    need = max(cfg.min_inliers, int(cfg.min_inlier_fraction * n_pts))
    if n_pts < max(3, cfg.min_inliers):
        return None
    cos_tilt = np.cos(np.deg2rad(cfg.max_tilt_deg))
    xy0 = O[:, :2].mean(axis=0) if len(O) else P[:, :2].mean(axis=0)
    hyps: list[tuple[int, float, np.ndarray, float]] = []
    S = P[rng.choice(n_pts, cfg.ransac_points, replace=False)] if n_pts > cfg.ransac_points else P
    idx = rng.integers(0, len(S), size=(cfg.iterations, 3))
    for i0, i1, i2 in idx:
        a, b, c = S[i0], S[i1], S[i2]
        n = np.cross(b - a, c - a)
        nn = np.linalg.norm(n)
        if nn < 1e-12:
            continue
        n = n / nn
        if n[2] < 0:
            n = -n
        if n[2] < cos_tilt:
            continue
        off = float(n @ a)
        count = int((np.abs(S @ n - off) <= cfg.inlier_m).sum())
        hyps.append((count, (off - n[0] * xy0[0] - n[1] * xy0[1]) / n[2], n, off))
    if not hyps:
        return None
    # group hypotheses into surfaces by height; the highest well-supported surface below the object wins
    hyps.sort(key=lambda h: -h[0])
    surfaces: list[tuple[int, float, np.ndarray, float]] = []
    for h in hyps:
        if all(abs(h[1] - g[1]) >= cfg.surface_gap_m for g in surfaces):
            surfaces.append(h)
    support = max(cfg.min_support_ratio * hyps[0][0], need * len(S) / n_pts, 3)
    eligible = [g for g in surfaces if g[0] >= support]
    if not eligible:
        return None
    _, _, n, off = max(eligible, key=lambda g: g[1])
    band = cfg.inlier_m
    inl = np.abs(P @ n - off) <= band
    for _ in range(2):
        Q = P[inl]
        cen = Q.mean(axis=0)
        _, _, vt = np.linalg.svd(Q - cen, full_matrices=False)
        n = vt[2] if vt[2, 2] >= 0 else -vt[2]
        off = float(n @ cen)
        r = P @ n - off
        mad = float(np.median(np.abs(r[inl] - np.median(r[inl])))) * 1.4826
        band = max(cfg.min_band_m, min(cfg.inlier_m, 3.0 * mad))
        inl = np.abs(r) <= band
        if inl.sum() < 3:
            return None
    if n[2] < cos_tilt or inl.sum() < need:
        return None
    xy = O[:, :2].mean(axis=0) if len(O) else P[inl, :2].mean(axis=0)
    height = (off - n[0] * xy[0] - n[1] * xy[1]) / n[2]
    if np.isfinite(z_max) and height > z_max:
        return None
    rms = float(np.sqrt(np.mean((P[inl] @ n - off) ** 2)))
    return TablePlane(float(height), n, off, int(inl.sum()), n_pts, rms)
