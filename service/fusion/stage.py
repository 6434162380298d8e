"""Fusion: the second SDF pass of Vysics (§4.B), vision depth terms + contact-induced terms.

S* = argmin_S  L_depth(S; rays)  +  2 L_sp(S)  +  1 L_hc(S)  +  1 L_cvx(S)

L_depth are BundleSDF's near-surface / empty / uncertain-free-space terms on the session's depth rays
(``service.sdf.fit_sdf``, the same as the first pass); L_sp, L_hc, L_cvx (``service.fusion.losses``) use
samples induced by the physible set P = {(p_i, n̂_i)} (``service.fusion.samples``): ray samples along
each n̂_i, cylinder lower-bound samples around points of the physible mesh on supporting planes of P,
convexity pairs between visible near-surface points and ray samples. The grid box covers the visible
surface ∪ P (padded), so contact points off the visible geometry can close the hidden side.
Output: S* and its zero level set (marching cubes, closed by construction).
References: Vysics paper §4.B and appendix; method-notes §6.2–6.3, §7.6.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Callable

import numpy as np

from service.errors import StageFailed
from service.fusion.losses import PhysibleLosses
from service.fusion.samples import hyperplane_anchors, hyperplane_samples, inside_box, ray_samples
from service.fusion.types import FusionConfig, FusionInputs, FusionOutputs
from service.mesh import Mesh
from service.sdf import extract_mesh, fit_sdf, hull_sdf, make_grid_geometry, rays_from_frame, sdf_query
from service.sdf.grid import grid_points
from service.sdf.types import RaySet, SdfGrid
from service.transforms import X_inv

Progress = Callable[[float, str], None] | None


def _sdf_extended(grid: SdfGrid, P: np.ndarray) -> np.ndarray:
    """S at points (P,3); outside the grid box the distance to the box is added to the border value."""
    b = grid.bounds_O
    out = np.linalg.norm(np.maximum(b[0] - P, 0) + np.maximum(P - b[1], 0), axis=1)
    return sdf_query(grid, P) + out


def select_frames(tracked: np.ndarray, max_frames: int) -> np.ndarray:
    """Indices (≤ max_frames,) evenly spread over the tracked frames."""
    idx = np.nonzero(np.asarray(tracked, bool))[0]
    if len(idx) <= max_frames:
        return idx
    return idx[np.unique(np.round(np.linspace(0, len(idx) - 1, max_frames)).astype(int))]


def session_rays(
    session, X_WO: np.ndarray, tracked: np.ndarray, cfg: FusionConfig, visible_sdf: SdfGrid | None = None
) -> RaySet:
    """Depth rays in O of up to ``cfg.max_frames`` tracked frames (subsampled pixels).

    As in the first pass, an object pixel is used only when its back-projected point lies above the table
    (by ``cfg.table_clearance``) and, given the visible SDF, within ``cfg.denoise`` of its zero level set
    (BundleSDF drops rays > 2 cm from its point cloud)."""
    rng = np.random.default_rng(cfg.seed)
    K = np.asarray(session.K, float)
    parts = []
    for i in select_frames(tracked, cfg.max_frames):
        X_OC = X_inv(X_WO[i]) @ session.X_WC
        depth, mask = session.depth(int(i)), session.mask(int(i))
        v, u = np.nonzero(mask & (depth > 0))
        d = depth[v, u].astype(float)
        P_C = np.stack([(u - K[0, 2]) / K[0, 0] * d, (v - K[1, 2]) / K[1, 1] * d, d], 1)
        P_W = P_C @ session.X_WC[:3, :3].T + session.X_WC[:3, 3]
        ok = P_W[:, 2] > session.table_height + cfg.table_clearance
        if visible_sdf is not None and len(P_C):
            P_O = P_C @ X_OC[:3, :3].T + X_OC[:3, 3]
            ok &= np.abs(_sdf_extended(visible_sdf, P_O)) < cfg.denoise
        keep = np.zeros(mask.shape, bool)
        keep[v[ok], u[ok]] = True
        parts.append(
            rays_from_frame(
                depth,
                mask,
                K,
                X_OC,
                stride=cfg.ray_stride_px,
                ring_px=cfg.ring_px,
                max_object_rays=cfg.max_object_rays_per_frame,
                max_free_rays=cfg.max_free_rays_per_frame,
                keep=keep,
                rng=rng,
            )
        )
    if not parts:
        raise StageFailed("fusion", "no tracked frame to take depth rays from")
    return RaySet.concatenate(parts)


def fusion_bounds(
    visible_points: np.ndarray, visible_sdf: SdfGrid | None, physible_points: np.ndarray, pad: float
) -> np.ndarray:
    """(2,3) box covering the visible points (0.5–99.5 % quantiles), the visible grid's box and the
    physible points, padded by ``pad``."""
    lo, hi = np.quantile(visible_points, 0.005, axis=0), np.quantile(visible_points, 0.995, axis=0)
    if visible_sdf is not None:
        b = visible_sdf.bounds_O
        lo, hi = np.minimum(lo, b[0] + pad), np.maximum(hi, b[1] - pad)
    if len(physible_points):
        lo = np.minimum(lo, physible_points.min(0))
        hi = np.maximum(hi, physible_points.max(0))
    return np.stack([lo - pad, hi + pad])


def _near_visible_box(points: np.ndarray, visible_points: np.ndarray, dist: float) -> np.ndarray:
    lo, hi = visible_points.min(0), visible_points.max(0)
    d = np.linalg.norm(np.maximum(lo - points, 0) + np.maximum(points - hi, 0), axis=1)
    return d <= dist


def fuse(
    rays: RaySet,
    visible_sdf: SdfGrid | None,
    physible_points_O: np.ndarray,
    physible_normals_O: np.ndarray,
    physible_mesh: Mesh | None,
    cfg: FusionConfig,
    *,
    progress: Progress = None,
    halfspace_O: np.ndarray | None = None,
) -> FusionOutputs:
    """The fusion pass on prepared rays (no session I/O); see the module docstring. ``halfspace_O``: optional
    plane (n, b) in O; where ``n·p + b > 0`` is outside the object (space below the table at frame 0)."""
    t0 = time.perf_counter()
    rng = np.random.default_rng(cfg.seed)
    vis = rays.surface_points_O
    if len(vis) < 4:
        raise StageFailed("fusion", f"only {len(vis)} observed object points in the selected frames")
    P = np.asarray(physible_points_O, float).reshape(-1, 3)
    N = np.asarray(physible_normals_O, float).reshape(-1, 3)
    if P.shape != N.shape:
        raise ValueError(f"physible points {P.shape} and normals {N.shape} differ in shape")
    ok = np.all(np.isfinite(P), 1) & np.all(np.isfinite(N), 1) & (np.linalg.norm(N, axis=1) > 1e-9)
    ok &= _near_visible_box(P, vis, cfg.max_physible_distance)
    n_dropped = int(len(P) - ok.sum())
    P, N = P[ok], N[ok] / np.linalg.norm(N[ok], axis=1, keepdims=True)

    bounds = fusion_bounds(vis, visible_sdf, P, cfg.pad)

    # sample pools
    x_sp, l_sp = ray_samples(P, N, cfg.extents, rng)
    if physible_mesh is not None and len(P):
        A, M = hyperplane_anchors(physible_mesh, P, N, rng, n_surface=cfg.anchor_samples, tol=cfg.anchor_tol)
    else:
        A, M = np.zeros((0, 3)), np.zeros((0, 3))
    n_anchors = len(A)
    if len(A) > cfg.max_anchors:
        k = rng.choice(len(A), cfg.max_anchors, replace=False)
        A, M = A[k], M[k]
    q_hc, b_hc = hyperplane_samples(A, M, cfg.extents, rng)
    keep = inside_box(x_sp, bounds)
    x_sp, l_sp = x_sp[keep], l_sp[keep]
    keep = inside_box(q_hc, bounds)
    q_hc, b_hc = q_hc[keep], b_hc[keep]
    s_vis = vis if len(vis) <= cfg.max_visible_points else vis[rng.choice(len(vis), cfg.max_visible_points, replace=False)]
    losses = PhysibleLosses(x_sp, l_sp, q_hc, b_hc, s_vis, cfg.weights, cfg.sdf.trunc, seed=cfg.seed)

    init = visible_sdf
    if cfg.init == "hull":
        origin, voxel, shape = make_grid_geometry(bounds, cfg.sdf.resolution)
        pts = np.concatenate([vis, P]) if len(P) else vis
        try:
            v0 = hull_sdf(pts, grid_points(origin, voxel, shape).reshape(-1, 3)).reshape(shape).astype(np.float32)
            init = SdfGrid(origin_O=origin, voxel=voxel, values=v0)
        except Exception:  # flat or degenerate point set (qhull): keep the visible start
            pass
    t_prep = time.perf_counter() - t0

    def fit_progress(frac: float, msg: str) -> None:
        if progress is not None:
            progress(0.05 + 0.9 * frac, msg)

    sdf_cfg = replace(cfg.sdf, seed=cfg.seed)
    grid = fit_sdf(rays, sdf_cfg, init=init, extra_losses=[losses], bounds_O=bounds, progress=fit_progress,
                   halfspace_O=halfspace_O)
    t_fit = time.perf_counter() - t0 - t_prep
    mesh = extract_mesh(grid)
    if mesh.is_empty:
        raise StageFailed("fusion", "the fused SDF has no zero level set inside its grid")
    tm = mesh.to_trimesh()
    if not tm.is_watertight:
        raise StageFailed("fusion", "the fused mesh is not watertight")
    metrics = {
        "rays": float(len(rays)),
        "physible_points": float(len(P)),
        "physible_dropped": float(n_dropped),
        "anchors": float(n_anchors),
        "sp_samples": float(len(x_sp)),
        "hc_samples": float(len(q_hc)),
        "voxel_m": float(grid.voxel),
        "volume_m3": float(tm.volume),
        "time_prepare_s": t_prep,
        "time_fit_s": t_fit,
        **{f"final_loss_{k}": v for k, v in losses.last.items()},
    }
    if progress is not None:
        progress(1.0, "fusion done")
    return FusionOutputs(sdf=grid, mesh=mesh, metrics=metrics)


def run(inputs: FusionInputs, cfg: FusionConfig, *, progress: Progress = None) -> FusionOutputs:
    """Fusion stage entry point: rays of the tracked frames, then ``fuse``."""
    n = inputs.session.n_frames
    X_WO = np.asarray(inputs.X_WO, float)
    tracked = np.asarray(inputs.tracked, bool)
    if X_WO.shape != (n, 4, 4):
        raise ValueError(f"FusionInputs.X_WO: expected shape ({n}, 4, 4), got {X_WO.shape}")
    if tracked.shape != (n,):
        raise ValueError(f"FusionInputs.tracked: expected shape ({n},), got {tracked.shape}")
    if progress is not None:
        progress(0.0, "fusion: reading depth rays")
    t0 = time.perf_counter()
    rays = session_rays(inputs.session, X_WO, tracked, cfg, inputs.visible_sdf)
    t_rays = time.perf_counter() - t0
    halfspace = None
    if cfg.below_table_outside:  # the object rests on the table at frame 0: nothing of it lies below
        from service.tracking.visible import below_table_halfspace

        halfspace = below_table_halfspace(X_WO[0], float(inputs.session.table_height))
    out = fuse(
        rays,
        inputs.visible_sdf,
        inputs.physible_points_O,
        inputs.physible_normals_O,
        inputs.physible_mesh,
        cfg,
        progress=progress,
        halfspace_O=halfspace,
    )
    out.metrics["time_rays_s"] = t_rays
    return out
