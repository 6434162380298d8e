"""Rays for the visible-geometry SDF and the visible point set V (Vysics §IV-A).

Rays: from up to ``sdf_frames`` tracked frames, object pixels (mask, depth, above the table) whose back-projected
point lies within ``sdf_denoise`` of the tracked object model (BundleSDF drops rays > 2 cm from its point
cloud), plus free rays in the dilated ring around the mask; all expressed in O with the tracked X_OC = X_OW X_WC.

Carved initialisation (``carved_init``, ``sdf_carve_init``): the fit starts from the convex hull of the observed
surface points, which also fills whatever lies between them — the mouth and the cavity of an open mug, the air
beside a prism's ridge. Voxels of the hull that a keyframe saw through (``FreeSpace``: the depth reading there
lies more than the carve margin behind the voxel) are set outside, S ← max(S, ``sdf_carve_value``), before the
fit; the free-space term of the fit alone, an L1 push of weight 1 against the band term's 3000, leaves most of
them filled. Support closure (``sdf_support_hull``): the hull also takes the seen points' feet on the frame-0 table
plane, except in columns that reach seen-empty space before a seen surface going up (``open_columns``: a cavity
seen into from above), and not at all when most of what it adds is so (``sdf_support_open_gate``: a mug).

Silhouette readings (``sdf_silhouette_px``, off): the object rays next to the object's outline against the
background (``silhouette_pixels``), or those of them that lie behind the plane of the mask's interior (``blended_pixels``:
the sensor's blend of object and background depth), get no band behind the reading or no ray at all.

Other views' evidence: ``drop_contradicted`` (``sdf_drop_contradicted``) drops the object rays whose surface point
another of the frames saw in front of its own reading (``service.sdf.contradicted_readings``: flying pixels,
misregistered edges).

V: vertices of the convex hull of the visible mesh plus ``visible_samples`` area-uniform samples on the hull,
kept when, in at least one checked frame, the point projects inside the object mask with observed depth
agreeing with its own depth, |z_point − z_obs| < ``visible_depth_tol``. Where the support closure shaped the start
(``visible_hull_seen``), the hull is that of the mesh vertices passing the same check: the hull of the whole mesh
spans the unseen closure, which lies a few millimetres outside the seen band.
"""

from __future__ import annotations

import numpy as np

from service.mesh import Mesh
from service.sdf import RaySet, rays_from_frame
from service.tracking.geometry import edge_tol
from service.transforms import X_inv, project_to_pixels


def pick_frames(tracked: np.ndarray, n: int) -> np.ndarray:
    """Up to n tracked frame indices, evenly spread (always including the first tracked frame)."""
    idx = np.nonzero(tracked)[0]
    if len(idx) <= n:
        return idx
    return idx[np.unique(np.round(np.linspace(0, len(idx) - 1, n)).astype(int))]


def below_table_halfspace(X_WO0: np.ndarray, table_height: float) -> np.ndarray:
    """(4,) plane (n, b) in O with n·p_O + b = table_height − z_W(p) at frame 0: positive below the table, where
    nothing of the object can be (it rests on the table in the first frame)."""
    return np.concatenate([-X_WO0[2, :3], [table_height - X_WO0[2, 3]]])


def silhouette_pixels(depth: np.ndarray, mask: np.ndarray, px: int, jump: float) -> np.ndarray:
    """(H,W) bool: pixels of ``mask`` (H,W) bool with a reading in ``depth`` (H,W) m that lie within ``px`` pixels of a
    non-mask pixel behind them (a reading farther than theirs by more than ``jump`` + 2 % of their depth, or no
    reading) and of no non-mask pixel in front of them by as much (an occluder). There the line of sight leaves the
    object: it grazes its outline (a limb, an edge), so the object is thin along it behind the reading, and a depth
    sensor blends the object's and the background's depth over a few pixels (flying pixels, edge fattening). Where
    an occluder bounds the mask, the object goes on behind it and the pixel is not a silhouette."""
    import cv2

    if px <= 0:
        return np.zeros(mask.shape, bool)
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * px + 1, 2 * px + 1))
    out = ~mask
    d = depth.astype(np.float32)
    behind = cv2.dilate(np.where(out, np.where(d > 0, d, np.float32(np.inf)), np.float32(0)), k)  # farthest outside
    front = cv2.erode(np.where(out & (d > 0), d, np.float32(np.inf)), k)  # nearest outside reading
    tol = edge_tol(d, jump)
    return mask & (d > 0) & (behind > d + tol) & ~(front < d - tol)


def blended_pixels(depth: np.ndarray, mask: np.ndarray, px: int, jump: float, margin: float,
                   radius: int | None = None) -> np.ndarray:
    """(H,W) bool: ``silhouette_pixels`` (within ``px``) whose reading lies more than ``margin`` (m) behind the
    surface of the mask's interior: the plane z(u, v) fitted by least squares to the readings of mask pixels more
    than ``px`` from the mask's edge within ``radius`` pixels (default px + 4), at least 10 of them. A depth sensor
    blends the object's depth with the background's over a few pixels at a silhouette; the blend lies between the
    two, behind the object's surface, in space the object does not fill (and that the camera cannot see: it is in
    the object's shadow), so the reading is not the object's. One image does not tell such a blend from a narrow
    face seen at grazing next to the outline (a box's top beside its front face): that face lies behind the
    interior's plane too (docs/tracking-findings.md, "The real cube's long extent")."""
    import cv2

    sil = silhouette_pixels(depth, mask, px, jump)
    if not sil.any():
        return sil
    r = px + 4 if radius is None else int(radius)
    inner = (mask & (depth > 0) & (cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5) > px + 0.5))
    H, W = depth.shape
    vg, ug = np.mgrid[0:H, 0:W].astype(np.float64)
    w = inner.astype(np.float64)
    z = np.where(inner, depth, 0.0).astype(np.float64)
    ys, xs = np.nonzero(sil)
    box = (2 * r + 1, 2 * r + 1)

    def S(a):  # window sums at the silhouette pixels
        return cv2.boxFilter(a, cv2.CV_64F, box, normalize=False, borderType=cv2.BORDER_CONSTANT)[ys, xs]

    n, su, sv, sz = S(w), S(w * ug), S(w * vg), S(z)
    suu, suv, svv, suz, svz = S(w * ug * ug), S(w * ug * vg), S(w * vg * vg), S(z * ug), S(z * vg)
    A = np.stack([np.stack([suu, suv, su], -1), np.stack([suv, svv, sv], -1), np.stack([su, sv, n], -1)], -2)
    b = np.stack([suz, svz, sz], -1)
    ok = n >= 10
    ok[ok] &= np.abs(np.linalg.det(A[ok])) > 1e-6 * np.maximum(n[ok], 1) ** 3
    out = np.zeros_like(sil)
    if ok.any():
        coef = np.linalg.solve(A[ok], b[ok][..., None])[..., 0]
        pred = coef[:, 0] * xs[ok] + coef[:, 1] * ys[ok] + coef[:, 2]
        out[ys[ok], xs[ok]] = depth[ys[ok], xs[ok]] - pred > margin
    return out


def sdf_rays(session, X_WO: np.ndarray, frames: np.ndarray, model_tree, cfg, rng: np.random.Generator,
             carver=None) -> RaySet:
    """Depth rays in O of ``frames`` (see module docstring). ``carver``: optional
    ``service.tracking.tracker.FreeSpace``; object points some keyframe saw through are dropped."""
    from service.tracking.tracker import near_effector

    import cv2

    K = session.K
    frames_in = []
    for i in frames:
        depth = session.depth(int(i))
        mask = session.mask(int(i))
        X_OC = X_inv(X_WO[i]) @ session.X_WC
        grid = np.zeros(mask.shape, bool)
        grid[::cfg.sdf_stride, ::cfg.sdf_stride] = True
        m_obj = mask
        if cfg.sdf_erode_px > 0:  # mask edges mix object and background depth (edge fattening of depth sensors)
            k = 2 * cfg.sdf_erode_px + 1
            m_obj = cv2.erode(mask.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))) > 0
        sel = m_obj & (depth > 0) & grid
        v, u = np.nonzero(sel)
        d = depth[v, u]
        P_C = np.stack([(u - K[0, 2]) / K[0, 0] * d, (v - K[1, 2]) / K[1, 1] * d, d], 1)
        P_O = P_C @ X_OC[:3, :3].T + X_OC[:3, 3]
        P_W = P_C @ session.X_WC[:3, :3].T + session.X_WC[:3, 3]
        dist, _ = model_tree.query(P_O, distance_upper_bound=cfg.sdf_denoise)
        ok = np.isfinite(dist) & (P_W[:, 2] > session.table_height + cfg.table_clearance)
        ok &= ~near_effector(session, int(i), P_W, cfg)
        if carver is not None and ok.any():
            st = carver.seen_through(P_O[ok])
            if st.mean() > cfg.carve_frame_frac:
                continue  # inconsistent with the space the keyframes saw empty: wrong pose or clutter
            ok[ok] &= ~st
        sil = None
        if cfg.sdf_silhouette_px:
            sil = silhouette_pixels(depth, mask, cfg.sdf_silhouette_px, cfg.edge_jump) \
                if cfg.sdf_silhouette_margin is None else \
                blended_pixels(depth, mask, cfg.sdf_silhouette_px, cfg.edge_jump, cfg.sdf_silhouette_margin)
            if cfg.sdf_silhouette_drop:  # not the object's surface: no ray
                ok &= ~sil[v, u]
                sil = None
        frames_in.append((int(i), depth, mask, X_OC, u, v, P_O, ok, sil))
    if carver is not None:
        # second pass: the frames that passed also carve each other's points
        from service.tracking.tracker import FreeSpace

        fs = FreeSpace(K, session.X_WC, carver.margin, carver.px)
        for i, depth, *_ in frames_in:
            fs.add(i, depth, X_WO[i])
        for f in frames_in:
            ok = f[7]
            if ok.any():
                ok[ok] &= ~fs.seen_through(f[6][ok])
    parts = []
    for i, depth, mask, X_OC, u, v, P_O, ok, sil in frames_in:
        keep = np.zeros(mask.shape, bool)
        keep[v[ok], u[ok]] = True
        back = None
        if sil is not None:  # silhouette readings: no band (or a thin one) behind them
            back = np.where(sil, cfg.sdf_silhouette_back, np.nan)
        parts.append(rays_from_frame(depth, mask, K, X_OC, stride=cfg.sdf_stride, ring_px=cfg.sdf_ring_px,
                                     max_object_rays=2000, max_free_rays=1500, keep=keep, rng=rng, back=back))
    if not parts:
        from service.errors import StageFailed

        raise StageFailed("tracking", f"none of the {len(frames)} frames picked for the visible SDF is consistent with "
                                      f"the free space seen by the keyframes (more than {cfg.carve_frame_frac:.0%} of "
                                      "their object points seen through): the track is wrong")
    return RaySet.concatenate(parts)


def support_feet(P_O: np.ndarray, halfspace_O: np.ndarray) -> np.ndarray:
    """(K,3) feet of points (K,3) on the table plane ``halfspace_O`` = (n, b) of ``below_table_halfspace`` (n·p + b
    = 0 on the table, n pointing down): p − (n·p + b) n. Points below the plane are their own feet."""
    hs = np.asarray(halfspace_O, float).reshape(4)
    n = hs[:3] / max(np.linalg.norm(hs[:3]), 1e-12)
    b = hs[3] / max(np.linalg.norm(hs[:3]), 1e-12)
    P = np.asarray(P_O, float)
    h = np.minimum(P @ n + b, 0.0)
    return P - h[:, None] * n[None, :]


def open_columns(idx: np.ndarray, P: np.ndarray, origin: np.ndarray, voxel: float, shape: tuple[int, int, int],
                 carved: np.ndarray, surface: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(len(idx),) bool: voxels ``idx`` (flat indices of the grid points P (M,3)) whose column upward (unit ``up``,
    steps of one voxel, nearest voxel) reaches a ``carved`` voxel (flat (M,) bool: seen empty) before a
    ``surface`` voxel (flat (M,) bool: near a seen point). Such a voxel lies under space the camera looked into
    without meeting the object — a cavity seen from above (a mug's mouth) — so the support argument (the object
    fills the space between a seen point and the table) does not reach it; under a seen surface it does."""
    shp = np.asarray(shape)
    carved3, surf3 = carved.reshape(shape), surface.reshape(shape)
    Q = P[idx]
    state = np.zeros(len(idx), np.int8)  # 0 open question, 1 a seen surface first, 2 seen-empty space first, 3 left
    for j in range(1, int(np.ceil(np.linalg.norm(shp))) + 1):
        und = np.nonzero(state == 0)[0]
        if len(und) == 0:
            break
        k = np.round((Q[und] + j * voxel * up - origin) / voxel).astype(int)
        inb = np.all((k >= 0) & (k < shp), 1)
        state[und[~inb]] = 3
        u2, k = und[inb], k[inb]
        sf = surf3[k[:, 0], k[:, 1], k[:, 2]]
        state[u2[sf]] = 1
        state[u2[~sf & carved3[k[:, 0], k[:, 1], k[:, 2]]]] = 2
    return state == 2


def carved_init(rays: RaySet, sdf_cfg, carver, value: float, support_O: np.ndarray | None = None,
                open_dilate: int | None = None, open_gate: float = 1.0, info: dict | None = None) -> "SdfGrid":
    """Initial SDF (the grid ``fit_sdf`` will use for ``rays`` and ``sdf_cfg``): the convex hull of the observed
    surface points, S = max over hull facets, with the voxels ``carver`` (``FreeSpace``; None: no carving) sees
    through set to at least ``value`` (m, > 0: outside).

    ``support_O`` (4,), optional: the table plane (n, b) at frame 0 (``below_table_halfspace``). The hull then also
    takes the foot of every observed point on it (``support_feet``; ``sdf_support_hull``): the object rests on the
    table, and the space between what was seen and the table that no keyframe saw empty — the part hidden by an
    occluder, the space under a never-seen back face — starts as object instead of air; the carving removes what
    a keyframe saw through (the table under an overhang, the air beside a slanted face).

    ``open_dilate`` (voxels, None: off; ``sdf_support_open``): the voxels the support closure adds to the hull of
    the seen points and whose column upward meets seen-empty space before a seen surface (``open_columns``; seen
    surface: the voxels of the observed points dilated by ``open_dilate``) keep the seen hull's start instead: the
    unseen part of a cavity whose mouth the camera looked into (a mug's cavity behind its near wall) is not closed;
    under a seen surface (a box's top, a prism's face, a mug's rim and wall) the closure stays. When more than
    ``open_gate`` of the added voxels are so, the object has a cavity the camera looked into and the whole closure
    is dropped (the start is the hull of the seen points, as without ``support_O``).

    ``info``: optional dict, receives ``added`` (voxels the closure adds to the seen hull), ``open`` (of them, under
    seen-empty space) and ``closure`` (whether the start keeps any of the closure)."""
    from service.sdf import SdfGrid
    from service.sdf.fit import default_bounds, hull_sdf, make_grid_geometry
    from service.sdf.grid import grid_points

    origin, voxel, shape = make_grid_geometry(default_bounds(rays, sdf_cfg.pad), sdf_cfg.resolution)
    P = grid_points(origin, voxel, shape).reshape(-1, 3)
    seen = rays.surface_points_O
    surf = seen
    if support_O is not None:
        surf = np.concatenate([surf, support_feet(surf, support_O)])
    S = hull_sdf(surf, P)
    inside = S < value
    opening = support_O is not None and open_dilate is not None
    if opening:
        S0 = hull_sdf(seen, P)  # the start without the closure (carved as below)
        inside |= S0 < value  # (each hull is simplified on its own: not quite nested)
    carved = np.zeros(len(P), bool)
    if carver is not None and inside.any():
        st = carver.seen_through(P[inside])
        carved[np.nonzero(inside)[0][st]] = True
        S[carved] = np.maximum(S[carved], value)
    if opening:
        S0[carved] = np.maximum(S0[carved], value)
        added = np.nonzero((S < 0) & (S0 >= 0))[0]
        if len(added):
            from scipy.ndimage import binary_dilation

            k = np.round((seen - origin) / voxel).astype(int)
            k = k[np.all((k >= 0) & (k < np.asarray(shape)), 1)]
            near = np.zeros(shape, bool)
            near[k[:, 0], k[:, 1], k[:, 2]] = True
            if open_dilate > 0:
                near = binary_dilation(near, iterations=int(open_dilate))
            hs = np.asarray(support_O, float).reshape(4)
            up = -hs[:3] / max(np.linalg.norm(hs[:3]), 1e-12)
            rev = added[open_columns(added, P, origin, voxel, shape, carved, near.reshape(-1), up)]
            S[rev] = S0[rev]
            gated = len(rev) > open_gate * len(added)
            if gated:  # a cavity seen into from above: no closure on this object
                S = S0
            if info is not None:
                info.update(added=int(len(added)), open=int(len(rev)), closure=not gated and len(rev) < len(added))
        elif info is not None:
            info.update(added=0, open=0, closure=False)
    elif info is not None and support_O is not None:
        info.update(closure=True)
    return SdfGrid(origin_O=origin, voxel=voxel, values=S.reshape(shape).astype(np.float32))


def _views(session, X_WO: np.ndarray, frames: np.ndarray) -> list:
    X_CW = X_inv(session.X_WC)
    return [(session.K, X_CW @ X_WO[int(i)], session.depth(int(i))) for i in frames]


def drop_contradicted(session, X_WO: np.ndarray, frames: np.ndarray, rays: RaySet, cfg) -> RaySet:
    """``rays`` without the object rays whose surface point a view of ``frames`` saw in front of its own reading by
    more than ``sdf_contradict_margin`` (``service.sdf.contradicted_readings``; ``sdf_drop_contradicted``)."""
    from service.sdf import contradicted_readings

    bad = contradicted_readings(rays, _views(session, X_WO, frames), margin=cfg.sdf_contradict_margin,
                                px=cfg.sdf_band_px, min_views=cfg.sdf_contradict_views)
    return rays.subset(~bad)


def visible_points(session, X_WO: np.ndarray, frames: np.ndarray, mesh: Mesh, cfg,
                   rng: np.random.Generator, hull_seen: bool | None = None) -> np.ndarray:
    """The visible set V (K,3) in O (see module docstring). ``hull_seen`` (None: ``cfg.visible_hull_seen``): the
    hull of the mesh's vertices that pass the visibility check instead of the hull of the whole mesh."""
    import trimesh

    if mesh.is_empty:
        return np.zeros((0, 3))
    hull = mesh.to_trimesh().convex_hull
    if cfg.visible_hull_seen if hull_seen is None else hull_seen:  # the hull of the mesh's vertices that pass the same check, not of the whole mesh
        vv = np.asarray(mesh.vertices, float)
        ok = _seen(session, X_WO, frames, vv, cfg.visible_depth_tol)
        if ok.sum() >= 4:
            try:
                hull = trimesh.points.PointCloud(vv[ok]).convex_hull
            except Exception:  # degenerate (flat) seen part: keep the whole mesh's hull
                pass
    cand = np.asarray(hull.vertices, float)
    if cfg.visible_samples > 0:
        samp, _ = trimesh.sample.sample_surface(hull, cfg.visible_samples, seed=int(rng.integers(1 << 31)))
        cand = np.concatenate([cand, np.asarray(samp, float)])
    return cand[_seen(session, X_WO, frames, cand, cfg.visible_depth_tol)]


def _seen(session, X_WO: np.ndarray, frames: np.ndarray, cand: np.ndarray, tol: float) -> np.ndarray:
    """(K,) bool: points (K,3) in O that project inside the object mask of at least one of ``frames`` with observed
    depth within ``tol`` of their own."""
    seen = np.zeros(len(cand), bool)
    K = session.K
    for i in frames:
        depth = session.depth(int(i))
        mask = session.mask(int(i))
        X_CO = X_inv(session.X_WC) @ X_WO[i]
        P = cand @ X_CO[:3, :3].T + X_CO[:3, 3]
        z = P[:, 2]
        u, v, inside = project_to_pixels(P, K, depth.shape)
        ui, vi = u[inside], v[inside]
        ok = mask[vi, ui] & (depth[vi, ui] > 0) & (np.abs(depth[vi, ui] - z[inside]) < tol)
        seen[np.nonzero(inside)[0][ok]] = True
    return seen
