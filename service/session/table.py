"""Table-plane detection from depth frames (used when ``table.height`` is null).

Points: for a few frames, valid depth pixels outside the dilated object mask are back-projected,
p_C = d K^-1 [u, v, 1]^T, and mapped to the world, p_W = X_WC p_C (a random subset of at most
``max_points``). The object's own points bound the table from above: z_max = (2nd percentile of the
object's z) + 2 cm; background points above z_max + ``inlier_m`` are dropped.

Candidate surfaces: W is z-up and the table is horizontal, so a table is a peak of the histogram of the
points' z (``bin_m`` bins, smoothed over 5 bins) while walls and clutter spread out. Peaks with at least
``min_support_ratio`` of the strongest peak's support (points within ``inlier_m``) and at least
``min_inliers`` / ``min_inlier_fraction`` are candidates; peaks closer than ``surface_gap_m`` merge.

Plane fit per candidate, highest first (the object rests on the table, so a floor or bench seen past the
table's edge is not taken for it, however large):
1. RANSAC in the slab |z - z_peak| <= ``slab_m``: planes n.p = c through 3 random slab points, kept only
   when near-horizontal (angle(n, z_W) <= ``max_tilt_deg``), scored by their inliers |n.p - c| <= ``inlier_m``;
2. total-least-squares refinement on all points (SVD of the centred inliers), twice, the inlier band
   shrinking to 3 robust sigmas (MAD), not below ``min_band_m``;
3. acceptance: still near-horizontal, enough inliers, height within ``surface_gap_m`` of the peak, and
   the camera does not see through it: few points lie ``below_gap_m``..``below_depth_m`` under it inside
   its (x, y) footprint (a horizontal slice through a wall or a box has about as many points just below it
   as on it; an opaque table hides what is under it).
The table height is the accepted plane's z at the object's centroid (x, y) (or at the inliers' centroid
when there are no object points). No accepted candidate -> None (the caller reports the error).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TablePlaneConfig:
    max_points: int = 40_000  # background points kept for the fit (over all frames)
    ransac_points: int = 4_000  # slab points on which RANSAC hypotheses are scored
    iterations: int = 200  # RANSAC hypotheses per candidate surface
    inlier_m: float = 0.01
    min_band_m: float = 0.002
    max_tilt_deg: float = 10.0
    min_inliers: int = 200
    min_inlier_fraction: float = 0.05
    bin_m: float = 0.005  # z histogram bin
    slab_m: float = 0.03  # RANSAC works on points within this of the peak's z
    surface_gap_m: float = 0.03  # peaks closer than this are one surface
    min_support_ratio: float = 0.1  # a surface needs this fraction of the best surface's support
    below_cell_m: float = 0.02  # footprint cells for the see-through test
    below_gap_m: float = 0.015  # "just below" the surface: from this far ...
    below_depth_m: float = 0.04  # ... to this far under it
    max_below_ratio: float = 0.2  # points seen just below / inliers, above which it is no surface
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


def _z_peaks(z: np.ndarray, cfg: TablePlaneConfig) -> list[tuple[float, int]]:
    """(z, support) of the histogram peaks of z, strongest first, merged within ``surface_gap_m``."""
    lo, hi = float(z.min()), float(z.max())
    nb = max(1, int(np.ceil((hi - lo) / cfg.bin_m)) + 1)
    hist, edges = np.histogram(z, bins=nb, range=(lo, lo + nb * cfg.bin_m))
    sm = np.convolve(np.pad(hist, 2).astype(float), np.array([1, 2, 3, 2, 1]) / 9.0, mode="valid")
    padded = np.r_[-1.0, sm, -1.0]
    is_peak = (padded[1:-1] >= padded[:-2]) & (padded[1:-1] > padded[2:]) & (sm > 0)
    zs = np.sort(z)
    peaks = []
    for i in np.nonzero(is_peak)[0]:
        zc = 0.5 * (edges[i] + edges[i + 1])
        band = zs[np.searchsorted(zs, zc - cfg.inlier_m) : np.searchsorted(zs, zc + cfg.inlier_m)]
        if len(band):
            zc = float(np.median(band))
        support = int(np.searchsorted(zs, zc + cfg.inlier_m) - np.searchsorted(zs, zc - cfg.inlier_m))
        peaks.append((zc, support))
    peaks.sort(key=lambda p: -p[1])
    merged: list[tuple[float, int]] = []
    for p in peaks:
        if all(abs(p[0] - q[0]) >= cfg.surface_gap_m for q in merged):
            merged.append(p)
    return merged


def _ransac(S: np.ndarray, cfg: TablePlaneConfig, cos_tilt: float, rng) -> tuple[np.ndarray, float] | None:
    """Best near-horizontal plane (n, c) through 3 random points of S (P,3), by inlier count."""
    if len(S) < 3:
        return None
    if len(S) > cfg.ransac_points:
        S = S[rng.choice(len(S), cfg.ransac_points, replace=False)]
    best, best_count = None, -1
    for i0, i1, i2 in rng.integers(0, len(S), size=(cfg.iterations, 3)):
        a = S[i0]
        n = np.cross(S[i1] - a, S[i2] - a)
        nn = np.linalg.norm(n)
        if nn < 1e-12:
            continue
        n = n / nn if n[2] >= 0 else -n / nn
        if n[2] < cos_tilt:
            continue
        off = float(n @ a)
        count = int((np.abs(S @ n - off) <= cfg.inlier_m).sum())
        if count > best_count:
            best, best_count = (n, off), count
    return best


def _refine(P: np.ndarray, n: np.ndarray, off: float, cfg: TablePlaneConfig):
    """Total-least-squares refits (SVD of the centred inliers), the band shrinking to 3 robust sigmas."""
    band = cfg.inlier_m
    inl = np.abs(P @ n - off) <= band
    for _ in range(2):
        if inl.sum() < 3:
            return None
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
    return n, off, inl


def _seen_below(P: np.ndarray, n: np.ndarray, off: float, inl: np.ndarray, cfg: TablePlaneConfig) -> float:
    """Points seen just below the surface, inside its (x, y) footprint, per inlier."""
    r = P @ n - off
    below = (r >= -cfg.below_depth_m) & (r <= -cfg.below_gap_m)
    if not below.any():
        return 0.0
    cell = np.floor(P[:, :2] / cfg.below_cell_m).astype(np.int64)
    key = cell[:, 0] * 1_000_003 + cell[:, 1]
    covered = np.isin(key[below], np.unique(key[inl]))
    return float(covered.sum()) / max(int(inl.sum()), 1)


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
        dil = cv2.dilate(m.astype(np.uint8), kernel) > 0 if cfg.mask_dilate_px > 0 else m
        bg_pts.append(back_project(d, K, X_WC, ~dil, per_frame, rng))
        obj_pts.append(back_project(d, K, X_WC, m, per_frame, rng))
    P = np.concatenate(bg_pts) if bg_pts else np.zeros((0, 3))
    O = np.concatenate(obj_pts) if obj_pts else np.zeros((0, 3))
    z_max = np.inf
    if len(O) >= 10:
        z_max = float(np.percentile(O[:, 2], 2)) + 0.02
        P = P[P[:, 2] <= z_max + cfg.inlier_m]
    n_pts = len(P)
    need = max(cfg.min_inliers, int(cfg.min_inlier_fraction * n_pts))
    if n_pts < max(3, cfg.min_inliers):
        return None
    cos_tilt = np.cos(np.deg2rad(cfg.max_tilt_deg))
    xy0 = O[:, :2].mean(axis=0) if len(O) else P[:, :2].mean(axis=0)
    peaks = _z_peaks(P[:, 2], cfg)
    strongest = peaks[0][1] if peaks else 0
    candidates = sorted(
        (p for p in peaks if p[1] >= max(need, cfg.min_support_ratio * strongest)), key=lambda p: -p[0]
    )
    for z_peak, _ in candidates:  # highest first
        slab = P[np.abs(P[:, 2] - z_peak) <= cfg.slab_m]
        hyp = _ransac(slab, cfg, cos_tilt, rng)
        if hyp is None:
            continue
        fit = _refine(P, hyp[0], hyp[1], cfg)
        if fit is None:
            continue
        n, off, inl = fit
        height = (off - n[0] * xy0[0] - n[1] * xy0[1]) / n[2]
        z_inl = float(np.median(P[inl, 2]))
        if n[2] < cos_tilt or inl.sum() < need or abs(z_inl - z_peak) > cfg.surface_gap_m:
            continue
        if np.isfinite(z_max) and height > z_max:
            continue
        if _seen_below(P, n, off, inl, cfg) > cfg.max_below_ratio:
            continue
        rms = float(np.sqrt(np.mean((P[inl] @ n - off) ** 2)))
        return TablePlane(float(height), n, off, int(inl.sum()), n_pts, rms)
    return None
