"""A dense signed-distance grid in the object frame O (metres), trilinearly interpolated, and the rays
and settings used to fit it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SdfGrid:
    origin_O: np.ndarray  # (3,) position of voxel (0,0,0) centre in O, m
    voxel: float  # voxel edge, m
    values: np.ndarray  # (nx,ny,nz) float32 signed distance, m (positive outside)
    observed: np.ndarray | None = None  # (nx,ny,nz) bool: voxel had direct supervision

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(int(n) for n in self.values.shape)  # type: ignore[return-value]

    @property
    def bounds_O(self) -> np.ndarray:
        """(2,3) min and max voxel centres in O."""
        lo = np.asarray(self.origin_O, float)
        return np.stack([lo, lo + self.voxel * (np.array(self.values.shape) - 1)])


@dataclass(frozen=True)
class RaySet:
    """Depth rays expressed in O, the supervision of :func:`service.sdf.fit_sdf`.

    A point at camera depth ``z`` (metres along the optical axis) on ray r is ``origins_O[r] + z * dirs_O[r]``
    (``dirs_O`` = R_OC K⁻¹ [u, v, 1]ᵀ, so its camera-z component is 1).

    - ``depth[r] > 0``: an object ray; the object surface was observed at depth ``depth[r]``.
    - ``depth[r] == 0``: a free ray (pixel in the dilated ring around the mask, not object). Space is known
      empty up to ``free_until[r] − τ`` (an occluder/background reading); ``free_until[r] = inf`` means no
      reading at all (BundleSDF's "uncertain free space").
    """

    origins_O: np.ndarray  # (R,3) camera centre in O, m
    dirs_O: np.ndarray  # (R,3) ray direction in O scaled to unit camera-z
    depth: np.ndarray  # (R,) observed object depth, m; 0 for free rays
    free_until: np.ndarray  # (R,) depth of the non-object reading of free rays (inf = none); ignored for object rays
    weight: np.ndarray  # (R,) ray weight
    back: np.ndarray | None = None  # (R,) depth of the band behind an object ray's reading, m (nan: the fit's
    # SdfConfig.trunc_back); None: every ray the fit's. A reading at a silhouette, where the line of sight grazes the
    # object, says nothing about the object behind it (service.tracking.visible.silhouette_pixels)

    def __post_init__(self):
        n = len(self.depth)
        for name in ("origins_O", "dirs_O"):
            a = getattr(self, name)
            if a.shape != (n, 3):
                raise ValueError(f"RaySet.{name}: expected shape ({n}, 3), got {a.shape}")
        for name in ("free_until", "weight") + (("back",) if self.back is not None else ()):
            a = getattr(self, name)
            if a.shape != (n,):
                raise ValueError(f"RaySet.{name}: expected shape ({n},), got {a.shape}")

    def __len__(self) -> int:
        return len(self.depth)

    @staticmethod
    def concatenate(parts: "list[RaySet]") -> "RaySet":
        back = None
        if any(p.back is not None for p in parts):
            back = np.concatenate([p.back if p.back is not None else np.full(len(p), np.nan) for p in parts])
        return RaySet(*(np.concatenate([getattr(p, f) for p in parts]) for f in ("origins_O", "dirs_O", "depth", "free_until", "weight")),
                      back=back)

    def subset(self, k: np.ndarray) -> "RaySet":
        """The rays selected by ``k`` (bool mask or indices)."""
        return RaySet(self.origins_O[k], self.dirs_O[k], self.depth[k], self.free_until[k], self.weight[k],
                      back=None if self.back is None else self.back[k])

    @property
    def surface_points_O(self) -> np.ndarray:
        """(K,3) observed object surface points of the object rays."""
        m = self.depth > 0
        return self.origins_O[m] + self.depth[m, None] * self.dirs_O[m]


@dataclass(frozen=True)
class SdfConfig:
    """Voxel-grid SDF fit (BundleSDF losses, method-notes §7.3/§7.6)."""

    resolution: int = 64  # voxels along the longest side of the bounds
    pad: float = 0.03  # m added around the observed surface when bounds are not given
    trunc: float = 0.01  # τ, m
    steps: int = 250
    rays_per_step: int = 2048
    samples_near: int = 16  # stratified in [d − 2τ, d + τ]
    samples_far: int = 16  # stratified from the grid entry to d − τ (or the free-ray end)
    lr: float = 0.3  # Adam learning rate in voxels (lr · voxel metres)
    lr_decay: float = 0.1  # lr · lr_decay^(step/steps)
    w_surface: float = 3000.0  # near-surface band, ((S − (d − z))/τ)²
    w_empty: float = 1.0  # empty space, |S/τ − 1|·[S < τ]
    w_uncertain: float = 50.0  # uncertain free space, (S/τ − 0.1)²·[S < 0.1τ]
    w_smooth: float = 20.0  # Laplacian smoothness, (ΔS·voxel/τ)² over the grid
    seed: int = 0
    threads: int = 1  # torch threads during the fit (small gathers: extra threads mostly contend)
    trunc_back: float | None = None  # depth of the band behind the observed surface (m; None: trunc, BundleSDF's
    # symmetric band). A surface reading only says the space right behind it is inside: with a band deeper than a
    # wall (mug, 6 mm) or a wedge (prism ridge), the fit fills the cavity/air behind it (docs/tracking-findings.md)

    def __post_init__(self) -> None:
        if self.trunc_back is not None and not 0 < self.trunc_back <= self.trunc:
            raise ValueError(f"SdfConfig.trunc_back must be in (0, trunc = {self.trunc}] or None, not {self.trunc_back!r}")

    @classmethod
    def fast(cls) -> "SdfConfig":
        return cls(resolution=32, steps=80, rays_per_step=512, samples_near=8, samples_far=8)
