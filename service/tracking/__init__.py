"""Tracking and visible geometry: X_WO(t) in every frame and the visible SDF/mesh/point set, from a validated
Session, with no pretrained model and no object model (the role BundleSDF plays in Vysics).

Entry point ``run(TrackingInputs, TrackingConfig, *, progress=None) -> TrackingOutputs``:
1. tracking (``service.tracking.tracker``): ORB+RANSAC coarse motion, point-to-plane ICP against the keyframe
   model, keyframe bundle adjustment (``service.tracking.posegraph``) and leave-one-out refinement, lost-track
   detection and re-localisation, interpolation of untracked frames;
2. velocities (``service.tracking.velocity``): median-filtered backward differences (method-notes §1.3);
3. visible SDF (``service.sdf.fit_sdf``) from the depth rays of tracked frames (without the readings other frames
   saw through, ``visible.drop_contradicted``), started from the hull of the seen points carved by the keyframes'
   free space (``visible.carved_init``; with ``sdf_support_hull`` the hull also takes the seen points' feet on the
   table, but not under a cavity seen into from above), marching cubes -> visible mesh;
4. visible set V (``service.tracking.visible``): convex-hull points of the mesh that pass a visibility check.
See docs/tracking.md (what the stage does now) and docs/tracking-findings.md (the experiments).
"""

from __future__ import annotations

import numpy as np

from service.errors import StageFailed
from service.sdf import extract_mesh, fit_sdf
from service.tracking.frames import FrameCache
from service.tracking.masks import TrimmedMasks
from service.tracking.tracker import track
from service.tracking.types import TrackingConfig, TrackingInputs, TrackingOutputs
from service.tracking.velocity import velocities
from service.tracking.visible import below_table_halfspace, drop_contradicted, carved_init, pick_frames, sdf_rays, visible_points

__all__ = ["run", "TrackingConfig", "TrackingInputs", "TrackingOutputs"]


def run(inputs: TrackingInputs, cfg: TrackingConfig = TrackingConfig(), *, progress=None) -> TrackingOutputs:
    """Track the object of ``inputs.session`` and reconstruct its visible geometry (frame O)."""
    # each image decoded once: the frames the visible-geometry passes read (if every frame is tracked) are kept
    s = FrameCache(inputs.session, pinned=_passes_frames(np.ones(inputs.session.n_frames, bool), cfg))
    if s.n_frames < 2:
        raise StageFailed("tracking", f"session {s.name} has {s.n_frames} frame(s); tracking needs at least 2")
    if s.K.shape != (3, 3) or s.X_WC.shape != (4, 4):
        raise StageFailed("tracking", f"session {s.name}: K must be 3x3 and X_WC 4x4")

    def rep(a: float, b: float):
        if progress is None:
            return None
        return lambda f, m: progress(a + (b - a) * f, m)

    rng = np.random.default_rng(cfg.seed)
    tr = track(s, cfg, rep(0.0, 0.6))
    v, w = velocities(s.frame_times, tr.X_WO, cfg.median_kernel)
    frames = pick_frames(tr.tracked, cfg.sdf_frames)
    s.repin(_passes_frames(tr.tracked, cfg))  # read by the passes below, several times each
    if progress is not None:
        progress(0.6, f"visible SDF from {len(frames)} frames")
    sv, strip = s, None  # the session as this stage reads it: masks trimmed by colour when they are off the object
    if cfg.mask_trim:
        trimmed = TrimmedMasks(s, cfg.mask_trim_px, cfg.mask_trim_iters)
        strip = trimmed.strip_fraction(frames, cfg.mask_trim_deep_px)
        if strip >= cfg.mask_trim_min:
            sv = trimmed
            if progress is not None:
                progress(0.6, f"masks trimmed by colour: {100 * strip:.1f} % of their pixels, "
                              f"{cfg.mask_trim_deep_px} px or more inside, look like background")
    rays = sdf_rays(sv, tr.X_WO, frames, tr.model.tree, cfg, rng, carver=tr.carver)
    halfspace = below_table_halfspace(tr.X_WO[0], s.table_height) if cfg.below_table_outside else None
    if cfg.sdf_drop_contradicted:  # the SDF's frames test each other's readings
        rays = drop_contradicted(sv, tr.X_WO, frames, rays, cfg)
    carver = tr.carver if cfg.sdf_carve_init else None
    support = halfspace if cfg.sdf_support_hull else None  # the hull closed down to the table (then carved)
    closure: dict = {}  # what the support closure added, whether it was kept (visible.carved_init)
    init = carved_init(rays, cfg.sdf, carver, cfg.sdf_carve_value, support_O=support,
                       open_dilate=cfg.sdf_support_open_dilate if cfg.sdf_support_open else None,
                       open_gate=cfg.sdf_support_open_gate, info=closure) \
        if carver is not None or support is not None else None
    grid = fit_sdf(rays, cfg.sdf, init=init, halfspace_O=halfspace, progress=rep(0.6, 0.95))
    mesh = extract_mesh(grid)
    if mesh.is_empty:
        raise StageFailed("tracking", "the visible SDF has no zero level set (no object surface reconstructed)")
    vis_frames = pick_frames(tr.tracked, cfg.visible_frames)
    V = visible_points(sv, tr.X_WO, vis_frames, mesh, cfg, rng,
                       hull_seen=cfg.visible_hull_seen and closure.get("closure", False))
    if halfspace is not None and len(V):
        V = V[V @ halfspace[:3] + halfspace[3] <= 1e-6]
    if progress is not None:
        progress(1.0, f"tracked {int(tr.tracked.sum())}/{s.n_frames} frames, |V| = {len(V)}")
    return TrackingOutputs(
        t=np.asarray(s.frame_times, float),
        X_WO=tr.X_WO,
        tracked=tr.tracked,
        v_WO_W=v,
        w_WO_O=w,
        sdf=grid,
        visible_mesh=mesh,
        visible_points_O=V,
        frames_lost=int((~tr.tracked).sum()),
        spin_axis_O=tr.spin.axis_O if tr.spin is not None and tr.spin.is_revolution else None,
        spin_observable=tr.spin.observable if tr.spin is not None and tr.spin.is_revolution else None,
        mask_strip_fraction=strip if strip is None or np.isfinite(strip) else None,
        masks_trimmed=sv is not s,
    )


def _passes_frames(tracked: np.ndarray, cfg: TrackingConfig) -> np.ndarray:
    """The frames the visible-geometry passes of ``run`` read, given which frames are tracked (N,) bool: the SDF's,
    the contradicted readings' (the SDF's) and the visible set's (``pick_frames``)."""
    return np.unique(np.concatenate([pick_frames(tracked, n) for n in (cfg.sdf_frames, cfg.visible_frames)]))
