"""Fusion: the second SDF pass of Vysics (§4.B), vision depth terms + contact-induced terms.

S* = argmin_S  L_depth(S; rays)  +  2 L_sp(S)  +  1 L_hc(S)  +  1 L_cvx(S)

L_depth are BundleSDF's near-surface / empty / uncertain-free-space terms on the session's depth rays
(``service.sdf.fit_sdf``, the same as the first pass); L_sp, L_hc, L_cvx (``service.fusion.losses``) use
samples induced by the physible set P = {(p_i, n̂_i)} (``service.fusion.samples``): ray samples along
each n̂_i, cylinder lower-bound samples around points of the physible mesh on supporting planes of P,
convexity pairs between visible near-surface points and ray samples. The grid box covers the visible
surface ∪ P (padded), so contact points off the visible geometry can close the hidden side.
Before sampling, P is filtered (departures from the paper, docs/fusion.md): points that some tracked pose
puts below the table or inside the end effector are dropped (non-penetration), so are points the camera saw
through (``service.fusion.carve``); table contacts (direction = the table's downward normal at a tracked frame,
on the table there) keep their supporting plane but are used as points only inside the footprint of the
other evidence, since a face resting on the table fixes the plane, not where on it the witness lies.
Output: S* and its zero level set (marching cubes, closed by construction).
References: Vysics paper §4.B and appendix; method-notes §6.2–6.3, §7.6.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Callable

import numpy as np

from service.errors import StageFailed
from service.fusion.carve import carve_grid, free_space_votes, open_unsupported
from service.fusion.losses import PhysibleLosses
from service.fusion.samples import hyperplane_anchors, hyperplane_samples, inside_box, ray_samples
from service.fusion.types import FusionConfig, FusionInputs, FusionOutputs
from service.mesh import Mesh
from service.sdf import extract_mesh, fit_sdf, hull_sdf, make_grid_geometry, rays_from_frame, sdf_query
from service.sdf.grid import grid_points
from service.sdf.types import RaySet, SdfGrid
from service.tracking.geometry import depth_continuous
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
    session, X_WO: np.ndarray, tracked: np.ndarray, cfg: FusionConfig, visible_sdf: SdfGrid | None = None,
    frames_out: list | None = None, flying_out: list | None = None,
) -> RaySet:
    """Depth rays in O of up to ``cfg.max_frames`` tracked frames (subsampled pixels).

    As in the first pass, an object pixel is used only when its back-projected point lies above the table
    (by ``cfg.table_clearance``) and, given the visible SDF, within ``cfg.denoise`` of its zero level set
    (BundleSDF drops rays > 2 cm from its point cloud). ``frames_out``, when given, receives
    ``(depth (H,W), X_OC (4,4), frame index, median |S_visible| of its object points (m, nan without the
    visible SDF))`` of every frame read (free-space test and pose check of the physible filters). ``flying_out``, when
    given, receives the (K,3) points in O of the object pixels only the flying-pixel test removed (``drop_flying``)."""
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
        smooth = np.ones(len(u), bool)
        if cfg.drop_flying:  # depth blended across a discontinuity, or a reading at an occluding contour
            smooth = depth_continuous(depth, u, v, cfg.edge_jump, holes=cfg.flying_holes)
        resid = np.nan
        if visible_sdf is not None and len(P_C):
            P_O = P_C @ X_OC[:3, :3].T + X_OC[:3, 3]
            dist = np.abs(_sdf_extended(visible_sdf, P_O))
            resid = float(np.median(dist[ok])) if ok.any() else np.nan
            ok &= dist < cfg.denoise
        if flying_out is not None and cfg.drop_flying:
            m = ok & ~smooth
            flying_out.append(P_C[m] @ X_OC[:3, :3].T + X_OC[:3, 3])
        ok &= smooth
        if frames_out is not None:
            frames_out.append((depth, X_OC, int(i), resid))
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


def table_contacts(
    points_O: np.ndarray, normals_O: np.ndarray, X_WO: np.ndarray, tracked: np.ndarray, table_height: float,
    max_deg: float = 5.0, tol: float = 0.005,
) -> np.ndarray:
    """(P,) bool: physible points that are table contacts, i.e. at some tracked frame k their outward direction
    is within ``max_deg`` of the table's downward normal in O, −R_WO(k)ᵀ e_z, and the point lies within ``tol``
    of the table plane. The rest are end-effector contacts (the sphere never pushes from below)."""
    P = np.asarray(points_O, float).reshape(-1, 3)
    N = np.asarray(normals_O, float).reshape(-1, 3)
    out = np.zeros(len(P), bool)
    if len(P) == 0:
        return out
    N = N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12)
    X = np.asarray(X_WO, float)[np.asarray(tracked, bool)]
    if len(X) == 0:
        return out
    down = -X[:, 2, :3]  # (K,3) table's downward normal in O at each tracked frame
    cos_ok = (N @ down.T) >= np.cos(np.radians(max_deg))  # (P,K)
    height = P @ X[:, 2, :3].T + X[:, 2, 3] - table_height  # (P,K) z_W − table
    return np.any(cos_ok & (np.abs(height) <= tol), axis=1)


def penetrating(
    points_O: np.ndarray, X_WO: np.ndarray, tracked: np.ndarray, table_height: float,
    p_WE: np.ndarray | None = None, ee_radius: float = 0.0, tol: float = 0.005,
) -> np.ndarray:
    """(P,) bool: points that would lie more than ``tol`` below the table, or inside the end-effector sphere
    (centre ``p_WE[k]``, radius ``ee_radius``), at some tracked frame k. No point of the object can: the
    non-penetration the contact model itself imposes, checked on every tracked pose."""
    P = np.asarray(points_O, float).reshape(-1, 3)
    out = np.zeros(len(P), bool)
    idx = np.nonzero(np.asarray(tracked, bool))[0]
    if len(P) == 0 or len(idx) == 0:
        return out
    X = np.asarray(X_WO, float)[idx]
    for a in range(0, len(idx), 64):
        Xa = X[a:a + 64]
        P_W = np.einsum("kij,pj->pki", Xa[:, :3, :3], P) + Xa[:, :3, 3]  # (P,k,3)
        out |= np.any(P_W[..., 2] < table_height - tol, axis=1)
        if p_WE is not None and ee_radius > 0:
            c = np.asarray(p_WE, float)[idx[a:a + 64]]
            ok = np.all(np.isfinite(c), axis=1)
            d = np.linalg.norm(P_W[:, ok] - c[ok], axis=2)
            out |= np.any(d < ee_radius - tol, axis=1)
    return out


def within_footprint(points_O: np.ndarray, normals_O: np.ndarray, evidence_O: np.ndarray, tol: float = 0.002,
                     max_evidence: int = 3000, seed: int = 0) -> np.ndarray:
    """(P,) bool: table-contact points (P,3) whose position across their plane (normal (P,3)) lies inside the
    shadow of the other evidence (K,3) along that normal, i.e. inside hull(E ∪ (E + L n̂)) within ``tol``.
    A face resting on the table fixes the plane; where on it the witness point lies is left to the rest.
    Normals within ~3° share one hull."""
    from scipy.spatial import ConvexHull

    P = np.asarray(points_O, float).reshape(-1, 3)
    N = np.asarray(normals_O, float).reshape(-1, 3)
    E = np.asarray(evidence_O, float).reshape(-1, 3)
    out = np.zeros(len(P), bool)
    if len(P) == 0 or len(E) < 4:
        return out
    if len(E) > max_evidence:
        E = E[np.random.default_rng(seed).choice(len(E), max_evidence, replace=False)]
    N = N / np.linalg.norm(N, axis=1, keepdims=True)
    L = 2.0 * float(np.ptp(np.concatenate([E, P]), axis=0).max() + 1.0)
    keys = np.round(N / 0.05).astype(int)
    _, group = np.unique(keys, axis=0, return_inverse=True)
    for g in np.unique(group):
        m = group.reshape(-1) == g
        n = N[m].mean(0)
        n /= np.linalg.norm(n)
        try:
            h = ConvexHull(np.concatenate([E, E + L * n]))
        except Exception:  # degenerate evidence (flat): no footprint
            continue
        out[m] = np.all(P[m] @ h.equations[:, :3].T + h.equations[:, 3] <= tol, axis=1)
    return out


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
    table_mask: np.ndarray | None = None,
    free_space: tuple[list, list, np.ndarray] | None = None,
    hull_extra_O: np.ndarray | None = None,
) -> FusionOutputs:
    """The fusion pass on prepared rays (no session I/O); see the module docstring. ``halfspace_O``: optional
    plane (n, b) in O; where ``n·p + b > 0`` is outside the object (space below the table at frame 0).
    ``table_mask`` (P,) bool: physible points that are table contacts; with ``cfg.table_points == "planes"``
    only their supporting planes are used (hyperplane anchors), not the points themselves.
    ``free_space`` = (depths [(H,W)], X_OC [(4,4)], K (3,3)): frames whose observed empty space is carved out of
    the fitted grid when ``cfg.carve_free_space`` (``service.fusion.carve.carve_grid``). ``hull_extra_O`` (K,3):
    further points of the hull start (no ray; e.g. the contour readings the flying-pixel test removed)."""
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
    table = np.zeros(len(P), bool) if table_mask is None else np.asarray(table_mask, bool).reshape(-1)
    if len(table) != len(ok):
        raise ValueError(f"table_mask has {len(table)} entries for {len(ok)} physible points")
    P, N, table = P[ok], N[ok] / np.linalg.norm(N[ok], axis=1, keepdims=True), table[ok]
    # points asserted to lie on the surface (support-point rays, convexity pairs, hull start)
    on = np.ones(len(P), bool)
    if cfg.table_points in ("planes", "footprint"):
        on = ~table
    if cfg.table_points == "footprint" and table.any():
        on[table] = within_footprint(P[table], N[table], np.concatenate([vis, P[~table]]), seed=cfg.seed)
    P_on, N_on = P[on], N[on]

    bounds = fusion_bounds(vis, visible_sdf, P, cfg.pad)

    # sample pools
    x_sp, l_sp = ray_samples(P_on, N_on, cfg.extents, rng)
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
        P_hull = P if cfg.table_points == "hull" else P_on
        pts = np.concatenate([vis, P_hull]) if len(P_hull) else vis
        if hull_extra_O is not None and len(hull_extra_O):
            pts = np.concatenate([pts, np.asarray(hull_extra_O, float).reshape(-1, 3)])
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
    # matter no evidence supports: what the camera saw through, then thin parts no observed point or contact touches
    fitted = grid
    n_carved = n_thin = 0
    if cfg.carve_free_space and free_space is not None and len(free_space[0]):
        grid, n_carved = carve_grid(grid, free_space[0], free_space[1], free_space[2], margin=cfg.carve_margin,
                                    radius_px=cfg.carve_radius_px, min_frac=cfg.carve_min_frac,
                                    min_frames=cfg.carve_min_frames)
    if cfg.thin_open_radius > 0:
        grid, n_thin = open_unsupported(grid, np.concatenate([vis, P]), cfg.thin_open_radius, cfg.thin_support)
    t_carve = time.perf_counter() - t0 - t_prep - t_fit
    mesh = extract_mesh(grid)
    fallback = grid is not fitted and (mesh.is_empty or not mesh.to_trimesh().is_watertight)
    if fallback:  # the removal left no closed surface: keep the fitted one
        grid, n_carved, n_thin = fitted, 0, 0
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
        "physible_table": float(table.sum()),
        "physible_table_as_points": float((table & on).sum()),
        "anchors": float(n_anchors),
        "sp_samples": float(len(x_sp)),
        "hc_samples": float(len(q_hc)),
        "voxel_m": float(grid.voxel),
        "volume_m3": float(tm.volume),
        "time_prepare_s": t_prep,
        "time_fit_s": t_fit,
        "carved_voxels": float(n_carved),
        "thin_unsupported_voxels": float(n_thin),
        "removal_fallback": float(fallback),
        "carved_frames": float(len(free_space[0]) if (cfg.carve_free_space and free_space is not None) else 0),
        "time_carve_s": t_carve,
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
    frames: list = []
    flying: list | None = [] if cfg.flying_in_hull else None
    rays = session_rays(inputs.session, X_WO, tracked, cfg, inputs.visible_sdf, frames_out=frames, flying_out=flying)
    t_rays = time.perf_counter() - t0
    P = np.asarray(inputs.physible_points_O, float).reshape(-1, 3)
    N = np.asarray(inputs.physible_normals_O, float).reshape(-1, 3)
    if P.shape != N.shape:
        raise ValueError(f"FusionInputs: physible points {P.shape} and normals {N.shape} differ in shape")
    n_free = 0
    if cfg.free_space_drop and len(P) and frames:  # free space seen by the camera overrides contact
        votes, n_obs = free_space_votes(P, [f[0] for f in frames], [f[1] for f in frames], inputs.session.K,
                                        margin=cfg.free_margin, radius_px=cfg.free_radius_px)
        free = (votes >= 1) & (votes >= cfg.free_min_frac * n_obs)
        n_free = int(free.sum())
        P, N = P[~free], N[~free]
    # poses checked for penetration: the frames read whose depth agrees with the visible SDF under the pose
    # (a wrong pose can sink the unseen part of the object into the table while its seen part still fits)
    checked = np.zeros(n, bool)
    for _, _, i, resid in frames:
        checked[i] = np.isfinite(resid) and resid <= cfg.pose_residual_max
    # free space of the pose-checked frames is carved out of the fitted grid (a wrong pose would carve the object)
    carve_frames = ([f[0] for f in frames if checked[f[2]]], [f[1] for f in frames if checked[f[2]]],
                    np.asarray(inputs.session.K, float))
    del frames
    n_pen = 0
    if cfg.drop_penetrating and len(P):  # contact points the tracked motion would push through table or robot
        pen = penetrating(P, X_WO, checked, float(inputs.session.table_height), inputs.session.p_WE,
                          float(inputs.session.ee_radius), cfg.penetration_tol)
        n_pen = int(pen.sum())
        P, N = P[~pen], N[~pen]
    table = table_contacts(P, N, X_WO, tracked, float(inputs.session.table_height), cfg.table_normal_deg,
                           cfg.table_tol)
    halfspace = None
    if cfg.below_table_outside:  # the object rests on the table at frame 0: nothing of it lies below
        from service.tracking.visible import below_table_halfspace

        halfspace = below_table_halfspace(X_WO[0], float(inputs.session.table_height))
    out = fuse(
        rays,
        inputs.visible_sdf,
        P,
        N,
        inputs.physible_mesh,
        cfg,
        progress=progress,
        halfspace_O=halfspace,
        table_mask=table,
        free_space=carve_frames,
        hull_extra_O=np.concatenate(flying) if flying else None,
    )
    out.metrics["time_rays_s"] = t_rays
    out.metrics["flying_hull_points"] = float(sum(len(f) for f in flying) if flying else 0)
    out.metrics["physible_free_dropped"] = float(n_free)
    out.metrics["physible_penetrating_dropped"] = float(n_pen)
    out.metrics["frames_pose_checked"] = float(checked.sum())
    return out
