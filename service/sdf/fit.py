"""Fitting a dense voxel-grid SDF to depth rays with BundleSDF's losses (CPU port, method-notes §7.3/§7.6).

Unknown: S, a (nx,ny,nz) grid of signed distances in O (m), trilinear between voxel centres.
For a sample at camera depth z on a ray with observed object depth d (τ = truncation):

- near-surface band, −τ_b ≤ z − d ≤ τ:       w_s · ((S − (d − z)) / τ)²   (τ_b = cfg.trunc_back, default τ;
                                                                           per ray ``RaySet.back`` where given)
- empty space, z < d − τ:                    w_e · |S/τ − 1| · [S < τ]          (one-sided toward +τ)
- free ring rays with a non-object reading f, z < f − τ: the same empty-space term
- free ring rays with no reading at all:     w_u · (S/τ − 0.1)² · [S < 0.1τ]     (uncertain free space)
- smoothness over the grid:                  w_lap · mean((ΔS)/τ)²              (discrete Laplacian)
- caller's extra terms ``extra(query_fn, step)`` (e.g. the fusion stage's support-point, hyperplane and
  convexity losses), added as they are.

Terms are means over all samples of the step (as BundleSDF), samples behind the band are unsupervised.
Minimised with Adam (lr = cfg.lr · voxel, exponential decay). Initialisation: a given grid (resampled), or
the convex hull of the observed surface points (S = max over hull facets of n·p + b, exact inside), which
closes the never-seen back side with the hull so the zero level set is a closed surface from the start.
Reference: Wen et al., "BundleSDF", CVPR 2023, and its config values (method-notes §7.1).
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
import torch

from service.sdf.grid import grid_points, query_torch, resample
from service.sdf.types import RaySet, SdfConfig, SdfGrid

QueryFn = Callable[[torch.Tensor], torch.Tensor]
ExtraLoss = Callable[[QueryFn, int], torch.Tensor]


def default_bounds(rays: RaySet, pad: float) -> np.ndarray:
    """(2,3) box around the observed surface points (robust 0.5–99.5 % quantiles) padded by ``pad``."""
    P = rays.surface_points_O
    if len(P) == 0:
        raise ValueError("RaySet has no object rays (depth > 0): cannot place the SDF grid")
    lo, hi = np.quantile(P, 0.005, axis=0), np.quantile(P, 0.995, axis=0)
    return np.stack([lo - pad, hi + pad])


def make_grid_geometry(bounds_O: np.ndarray, resolution: int) -> tuple[np.ndarray, float, tuple[int, int, int]]:
    """Origin, voxel edge and shape of a grid covering ``bounds_O`` (2,3) with ``resolution`` voxels on its
    longest side."""
    bounds_O = np.asarray(bounds_O, float)
    ext = bounds_O[1] - bounds_O[0]
    if np.any(ext <= 0):
        raise ValueError(f"bounds_O must have max > min on every axis, got {bounds_O.tolist()}")
    voxel = float(ext.max() / (resolution - 1))
    shape = tuple(int(np.ceil(e / voxel - 1e-9)) + 1 for e in ext)
    return bounds_O[0].copy(), voxel, shape  # type: ignore[return-value]


def hull_sdf(points_O: np.ndarray, query_O: np.ndarray, max_vertices: int = 400) -> np.ndarray:
    """Signed distance-like field of the convex hull of points (K,3) at query points (P,3): max over facets of
    the plane distance (exact inside and on the faces, a lower bound outside). The hull is simplified to at most
    ``max_vertices`` of its vertices (an inner approximation) to keep the facet count small."""
    from scipy.spatial import ConvexHull

    P = np.asarray(points_O, float)
    h = ConvexHull(P)
    V = P[h.vertices]
    if len(V) > max_vertices:
        V = V[np.random.default_rng(0).choice(len(V), max_vertices, replace=False)]
        h = ConvexHull(V)
    eq = torch.from_numpy(h.equations.astype(np.float32))  # (F,4): n·x + b <= 0 inside
    q = torch.from_numpy(np.asarray(query_O, np.float32))
    out = torch.empty(len(q))
    for a in range(0, len(q), 32768):
        out[a:a + 32768] = (q[a:a + 32768] @ eq[:, :3].T + eq[:, 3]).amax(1)
    return out.numpy().astype(np.float64)


def _ray_box(o: np.ndarray, d: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Entry/exit parameters (R,) of rays o + z·d through the box [lo, hi] (z ≥ 0)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / np.where(np.abs(d) < 1e-12, 1e-12, d)
        t1, t2 = (lo - o) * inv, (hi - o) * inv
    zin = np.maximum(np.minimum(t1, t2).max(1), 0.0)
    zout = np.maximum(t1, t2).min(1)
    return zin, zout


def fit_sdf(
    rays: RaySet,
    cfg: SdfConfig = SdfConfig(),
    *,
    init: SdfGrid | None = None,
    extra_losses: Sequence[ExtraLoss] = (),
    bounds_O: np.ndarray | None = None,
    halfspace_O: np.ndarray | None = None,
    progress: Callable[[float, str], None] | None = None,
) -> SdfGrid:
    """Fit a voxel SDF in O to ``rays`` (see module docstring) and return it.

    ``bounds_O`` (2,3) sets the grid box (default: observed surface padded by ``cfg.pad``); enlarge it to cover
    points other losses supervise. ``extra_losses`` are callables ``f(query_fn, step) -> scalar tensor`` with
    ``query_fn(points_O (P,3) float32 tensor) -> (P,) SDF``, differentiable; they are added to the loss.
    ``halfspace_O`` (4,) = (n, b) with unit n: the half-space n·p + b > 0 is known to be outside the object (e.g.
    below the table); the SDF is intersected with it, S ← max(S, n·p + b), in the initialisation, in every query
    of the fit and in the returned grid."""
    if len(rays) == 0:
        raise ValueError("fit_sdf: empty RaySet")
    n_threads = torch.get_num_threads()
    torch.set_num_threads(max(1, cfg.threads))
    try:
        return _fit(rays, cfg, init, extra_losses, bounds_O, progress, halfspace_O)
    finally:
        torch.set_num_threads(n_threads)


def _fit(rays, cfg, init, extra_losses, bounds_O, progress, halfspace_O=None) -> SdfGrid:
    gen = torch.Generator().manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    if bounds_O is None:
        bounds_O = default_bounds(rays, cfg.pad)
    origin, voxel, shape = make_grid_geometry(bounds_O, cfg.resolution)
    tau = float(cfg.trunc)
    back = (tau if cfg.trunc_back is None else float(cfg.trunc_back)) / tau  # band depth behind the surface, in τ

    if init is not None:
        v0 = resample(init, origin, voxel, shape)
    else:
        surf = rays.surface_points_O
        v0 = hull_sdf(surf, grid_points(origin, voxel, shape).reshape(-1, 3)).reshape(shape).astype(np.float32)
    hs = None
    if halfspace_O is not None:
        hs = np.asarray(halfspace_O, float).reshape(4)
        hs = hs / max(np.linalg.norm(hs[:3]), 1e-12)
        cut = (grid_points(origin, voxel, shape) @ hs[:3] + hs[3]).astype(np.float32)
        v0 = np.maximum(v0, cut)
    values = torch.nn.Parameter(torch.from_numpy(np.ascontiguousarray(v0, np.float32)))
    origin_t = torch.tensor(origin, dtype=torch.float32)
    hs_t = None if hs is None else torch.tensor(hs, dtype=torch.float32)

    def query_fn(p: torch.Tensor) -> torch.Tensor:
        s = query_torch(values, origin_t, voxel, p)
        if hs_t is not None:
            s = torch.maximum(s, p @ hs_t[:3] + hs_t[3])
        return s

    # per-ray sampling intervals, once
    lo, hi = origin, origin + voxel * (np.array(shape) - 1)
    zin, zout = _ray_box(rays.origins_O, rays.dirs_O, lo, hi)
    obj = rays.depth > 0
    far_end = np.where(obj, rays.depth - tau, np.minimum(zout, rays.free_until - tau))
    usable = (zout > zin) & ((obj & (rays.depth > zin)) | (~obj & (far_end > zin)))
    idx_all = np.nonzero(usable)[0]
    if len(idx_all) == 0:
        raise ValueError("fit_sdf: no ray crosses the grid bounds")
    O = torch.from_numpy(rays.origins_O.astype(np.float32))
    D = torch.from_numpy(rays.dirs_O.astype(np.float32))
    dep = torch.from_numpy(rays.depth.astype(np.float32))
    zin_t = torch.from_numpy(zin.astype(np.float32))
    far_t = torch.from_numpy(far_end.astype(np.float32))
    w_t = torch.from_numpy(rays.weight.astype(np.float32))
    back_t = None  # per-ray band depth behind the reading, in τ (RaySet.back; nan: the config's)
    if rays.back is not None:
        back_t = torch.from_numpy(np.where(np.isfinite(rays.back), rays.back / tau, back).astype(np.float32))
    uncertain_t = torch.from_numpy(~obj & ~np.isfinite(rays.free_until))
    obj_t = torch.from_numpy(obj)
    lo_t, hi_t = torch.tensor(lo, dtype=torch.float32), torch.tensor(hi, dtype=torch.float32)

    opt = torch.optim.Adam([values], lr=cfg.lr * voxel, betas=(0.9, 0.999), eps=1e-15)
    n_near, n_far = cfg.samples_near, cfg.samples_far
    ns = n_near + n_far
    B = min(cfg.rays_per_step, len(idx_all))
    for step in range(cfg.steps):
        lr = cfg.lr * voxel * cfg.lr_decay ** (step / max(cfg.steps, 1))
        for g in opt.param_groups:
            g["lr"] = lr
        r = torch.from_numpy(rng.choice(idx_all, B, replace=False))
        o, d, dd, z0, z1, w = O[r], D[r], dep[r], zin_t[r], far_t[r], w_t[r]
        isobj, isunc = obj_t[r], uncertain_t[r]
        u = (torch.arange(ns, dtype=torch.float32) + torch.rand(B, ns, generator=gen)) / ns  # stratified (B,ns)
        un = (torch.arange(n_near, dtype=torch.float32) + torch.rand(B, n_near, generator=gen)) / n_near
        uf = (torch.arange(n_far, dtype=torch.float32) + torch.rand(B, n_far, generator=gen)) / n_far
        bk = back if back_t is None else back_t[r][:, None]
        z_near = dd[:, None] + tau * ((2.0 + bk) * un - 2.0)  # [d − 2τ, d + τ_b]
        z_far = z0[:, None] + (z1 - z0).clamp(min=0)[:, None] * uf
        z_obj = torch.cat([z_near, z_far], 1)
        z_free = z0[:, None] + (z1 - z0).clamp(min=0)[:, None] * u
        z = torch.where(isobj[:, None], z_obj, z_free)  # (B,ns)
        p = o[:, None, :] + z[..., None] * d[:, None, :]
        inside = ((p >= lo_t) & (p <= hi_t)).all(-1)
        S = query_fn(p.reshape(-1, 3)).reshape(B, ns) / tau
        diff = (dd[:, None] - z) / tau
        band = isobj[:, None] & (diff <= 1.0) & (diff >= -bk) & inside
        empty = inside & ((isobj[:, None] & (diff > 1.0)) | (~isobj & ~isunc)[:, None] & (z < z1[:, None]))
        unc = inside & isunc[:, None]
        ww = w[:, None].expand(B, ns)
        n_tot = float(B * ns)
        loss = cfg.w_surface * (ww * band * (S - diff) ** 2).sum() / n_tot
        loss = loss + cfg.w_empty * (ww * empty * torch.relu(1.0 - S)).sum() / n_tot
        loss = loss + cfg.w_uncertain * (ww * unc * torch.relu(0.1 - S) ** 2).sum() / n_tot
        if cfg.w_smooth > 0:
            v = values
            lap = (v[2:, 1:-1, 1:-1] + v[:-2, 1:-1, 1:-1] + v[1:-1, 2:, 1:-1] + v[1:-1, :-2, 1:-1]
                   + v[1:-1, 1:-1, 2:] + v[1:-1, 1:-1, :-2] - 6.0 * v[1:-1, 1:-1, 1:-1]) / tau
            loss = loss + cfg.w_smooth * (lap ** 2).mean()
        for extra in extra_losses:
            loss = loss + extra(query_fn, step)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if progress is not None and (step % 20 == 0 or step == cfg.steps - 1):
            progress((step + 1) / cfg.steps, f"sdf step {step + 1}/{cfg.steps} loss {float(loss.detach()):.4g}")

    vals = values.detach().numpy().astype(np.float32)
    if hs is not None:
        vals = np.maximum(vals, cut)
    observed = np.zeros(shape, bool)
    surf = rays.surface_points_O
    if len(surf):
        k = np.round((surf - origin) / voxel).astype(int)
        ok = ((k >= 0) & (k < np.array(shape))).all(1)
        k = k[ok]
        rad = int(np.ceil(tau / voxel))
        for dx in range(-rad, rad + 1):
            for dy in range(-rad, rad + 1):
                for dz in range(-rad, rad + 1):
                    kk = np.clip(k + [dx, dy, dz], 0, np.array(shape) - 1)
                    observed[kk[:, 0], kk[:, 1], kk[:, 2]] = True
    return SdfGrid(origin_O=origin, voxel=voxel, values=vals, observed=observed)
