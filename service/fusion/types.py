"""Inputs and outputs of the fusion stage (second SDF pass with physible supervision)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from service.mesh import Mesh
from service.sdf.types import SdfConfig, SdfGrid
from service.session.types import Session


@dataclass(frozen=True)
class FusionInputs:
    session: Session
    X_WO: np.ndarray  # (N,4,4) tracked poses
    tracked: np.ndarray  # (N,) bool
    visible_sdf: SdfGrid  # warm start / grid extent
    physible_points_O: np.ndarray  # (P,3)
    physible_normals_O: np.ndarray  # (P,3)
    physible_mesh: Mesh


@dataclass(frozen=True)
class FusionOutputs:
    sdf: SdfGrid
    mesh: Mesh  # watertight, frame O
    metrics: dict[str, float] = field(default_factory=dict)  # sample counts, final loss terms, timings


@dataclass(frozen=True)
class SampleExtents:
    """Counts and extents (m) of the physible samples (service.fusion.samples).

    Defaults: the values printed in the paper's appendix (ray 5 mm / 5 mm / 10 cm; cylinders
    R 5 cm / 10 cm, far height 10 cm); ``final_code()`` gives the authors' last code (2 cm / 2 cm /
    4 cm; 2 / 4 / 4 cm). docs/fusion.md says why the default is the paper's.
    """

    ray_n_in: int = 100
    ray_n_out: int = 100
    ray_n_far: int = 50
    ray_d_in: float = 0.005
    ray_d_out: float = 0.005
    ray_d_far: float = 0.10
    hc_n_in: int = 200
    hc_n_near: int = 100
    hc_n_far: int = 100
    hc_h_in: float = 0.005
    hc_h_near: float = 0.005
    hc_r_near: float = 0.05
    hc_r_far: float = 0.10
    hc_h_far: float = 0.10

    @classmethod
    def paper_text(cls) -> "SampleExtents":
        return cls()

    @classmethod
    def final_code(cls) -> "SampleExtents":
        """The authors' final code (bundlesdf_interface.py, 2025-02): N_out 50, 2 cm / 2 cm / 4 cm rays,
        cylinders R 2 cm / 4 cm, far height 4 cm."""
        return cls(ray_n_out=50, ray_d_in=0.02, ray_d_out=0.02, ray_d_far=0.04,
                   hc_r_near=0.02, hc_r_far=0.04, hc_h_far=0.04)


@dataclass(frozen=True)
class LossWeights:
    """Weights of the contact-induced terms (paper appendix table) and samples drawn per step."""

    sp: float = 2.0
    hc: float = 1.0
    cvx: float = 1.0
    n_sp: int = 1000  # paper: up to 1K support-point pairs per step
    n_hc: int = 5000  # paper: up to 5K hyperplane pairs per step
    n_cvx: int = 2000
    eps_cvx: float = 0.01  # |S(s₁)| ≤ ε for the near-surface end of a convexity pair, m


def _default_sdf() -> SdfConfig:
    # lighter Laplacian than the first pass: on the hidden side it is the only other force on the
    # grid, and at w_smooth 20 it visibly inflates faces that only contact data supports
    return SdfConfig(resolution=80, steps=300, rays_per_step=2048, samples_near=24, samples_far=24, w_smooth=5.0)


@dataclass(frozen=True)
class FusionConfig:
    """Settings of the fusion SDF pass. ``fast()`` is the reduced preset used by tests.

    Every setting that changes the fused geometry lives here (the SDF fit of the second pass
    included), so a change of any of them invalidates fusion and what follows, not tracking/contact.
    """

    seed: int = 0
    sdf: SdfConfig = field(default_factory=_default_sdf)
    extents: SampleExtents = field(default_factory=SampleExtents)
    weights: LossWeights = field(default_factory=LossWeights)
    init: str = "hull"  # "hull": convex hull of visible ∪ physible points; "visible": the visible SDF
    max_frames: int = 40  # frames (evenly spaced among the tracked ones) whose rays are used
    ray_stride_px: int = 4
    ring_px: int = 30
    max_object_rays_per_frame: int = 1500
    max_free_rays_per_frame: int = 800
    table_clearance: float = 0.005  # object pixels must back-project this far above the table, m
    denoise: float = 0.02  # ... and within this of the visible SDF's zero level set, m
    # ... and, with drop_flying, not at a depth jump: every 4-neighbour has a reading within edge_jump + 2 % of its
    # depth (service.tracking.geometry.depth_continuous, the tracking points' flying-pixel test): a blend across a
    # discontinuity, or a contour reading whose near-surface band reaches past the silhouette edge. The removed
    # readings still join the hull start (flying_in_hull; without it round bodies and the prism shrink). docs/fusion.md
    drop_flying: bool = True
    edge_jump: float = 0.01  # m
    flying_holes: bool = True  # a neighbour without a reading counts as a jump (as in the tracking's test)
    flying_in_hull: bool = True  # the readings it removes still join the hull start (they give no ray)
    pad: float = 0.02  # m around visible ∪ physible points
    max_physible_distance: float = 0.15  # physible points farther than this from the visible box are dropped, m
    anchor_samples: int = 25_000  # surface samples of the physible mesh tested as hyperplane anchors
    anchor_tol: float = 1e-3  # m
    max_anchors: int = 1000  # anchors kept (random subset) to bound the hyperplane pool
    max_visible_points: int = 20_000  # near-surface pool for the convexity pairs
    below_table_outside: bool = True  # the object rests on the table at frame 0: space below it is outside
    # table contacts (service.fusion.stage.table_contacts): "points" = as every physible point (support-point
    # rays, convexity, hull start; the paper); "footprint" = as points only inside the footprint of the other
    # evidence, else their plane only; "planes" = their supporting planes only; "hull" = planes + hull start.
    # docs/fusion.md compares them.
    table_points: str = "points"
    table_normal_deg: float = 5.0  # a physible point is a table contact when its direction is within this of
    table_tol: float = 0.005  # ... the table's downward normal in O and it lies this close to the table, m, at a tracked frame
    # physible points below the table or inside the end effector at some pose-checked frame are dropped
    drop_penetrating: bool = True
    penetration_tol: float = 0.005  # m
    pose_residual_max: float = 0.005  # frames used for it: median |S_visible| of their depth points ≤ this, m
    # free-space evidence overrides physible points (service.fusion.carve)
    free_space_drop: bool = True
    free_margin: float = 0.01  # m in front of the (window-minimum) depth reading
    free_radius_px: int = 3  # window radius of the minimum depth
    free_min_frac: float = 0.2  # fraction of the frames observing a point that must find it empty
    # the same test on the fitted grid: voxels the camera saw through (pose-checked frames) are outside the fused
    # shape (service.fusion.carve.carve_grid; docs/fusion.md, "Free space carved out of the fused SDF")
    carve_free_space: bool = True
    carve_margin: float = 0.01  # m in front of the (window-minimum) depth reading
    carve_radius_px: int = 3
    carve_min_frac: float = 0.2  # of the frames that observe a voxel
    carve_min_frames: int = 2
    # thin parts (removed by an opening with a ball of this radius, m; 0 = off) farther than ``thin_support`` (m) from
    # every observed depth point and physible point are removed (service.fusion.carve.open_unsupported). Off: it also
    # removes acute edges only the contact planes support (prism, seed-11 bench: chamfer 1.42 -> 1.74 cm)
    thin_open_radius: float = 0.0
    thin_support: float = 0.004

    def __post_init__(self):
        if self.init not in ("visible", "hull"):
            raise ValueError(f"FusionConfig.init must be 'visible' or 'hull', got {self.init!r}")
        if self.table_points not in ("footprint", "planes", "hull", "points"):
            raise ValueError("FusionConfig.table_points must be 'footprint', 'planes', 'hull' or 'points', "
                             f"got {self.table_points!r}")
        for name in ("carve_margin", "carve_radius_px", "thin_open_radius", "thin_support", "edge_jump"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"FusionConfig.{name} must be >= 0, got {getattr(self, name)!r}")
        if not 0 <= self.carve_min_frac <= 1:
            raise ValueError(f"FusionConfig.carve_min_frac must be a fraction in [0, 1], got {self.carve_min_frac!r}")
        if not self.carve_min_frames >= 1:
            raise ValueError(f"FusionConfig.carve_min_frames must be >= 1, got {self.carve_min_frames!r}")

    @classmethod
    def fast(cls) -> "FusionConfig":
        return cls(
            sdf=SdfConfig(resolution=40, steps=120, rays_per_step=1024, samples_near=12, samples_far=12, w_smooth=5.0),
            weights=LossWeights(n_sp=500, n_hc=2000, n_cvx=1000),
            max_frames=8,
            ray_stride_px=4,
            max_object_rays_per_frame=600,
            max_free_rays_per_frame=300,
            anchor_samples=5000,
            max_anchors=200,
            max_visible_points=5000,
        )
