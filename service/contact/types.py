"""Inputs and outputs of contact-implicit dynamics learning (physible geometry and inertia)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from service.mesh import Mesh
from service.session.types import Friction


@dataclass(frozen=True)
class ContactInputs:
    """Trajectories in the PLL state layout, world frame with the table plane at ``table_height``.

    ``states[k]`` is (T_k,13): ``qw qx qy qz | x y z | wx wy wz (body) | vx vy vz (world)`` with
    backward-difference velocities (``p[t+1] = p[t] + dt v[t+1]``).
    """

    dt: float
    states: tuple[np.ndarray, ...]
    ee_p_W: tuple[np.ndarray, ...] | None  # (T_k,3) sphere centre per step, or None (no robot)
    ee_v_W: tuple[np.ndarray, ...] | None  # (T_k,3) sphere centre velocity (backward differences)
    ee_radius: float
    table_height: float
    friction: Friction
    mass: float  # kg (declared or default)
    mass_declared: bool
    visible_points_O: np.ndarray | None  # (K,3) visible set V, None = no vision term
    init_vertices_O: np.ndarray | None  # (V,3) initial geometry guess (e.g. hull of the visible mesh)


@dataclass(frozen=True)
class StepResiduals:
    """Per-transition dynamics residuals at the learned optimum (one row per transition)."""

    traj: np.ndarray  # (S,) trajectory index
    step: np.ndarray  # (S,) index k of the transition k -> k+1
    dv_observed: np.ndarray  # (S,6) observed [ω (body); v (world)] change minus gravity
    dv_explained: np.ndarray  # (S,6) change explained by the optimal contact impulses
    residual: np.ndarray  # (S,6) dv_observed - dv_explained
    phi_table: np.ndarray  # (S,) min signed gap object-table, m
    phi_ee: np.ndarray  # (S,) signed gap object-sphere, m (inf without robot)
    impulse_table: np.ndarray  # (S,) total normal impulse from the table, N s
    impulse_ee: np.ndarray  # (S,) normal impulse from the sphere, N s


@dataclass(frozen=True)
class ContactOutputs:
    physible_mesh: Mesh  # convex geometry in O
    mass: float
    com_O: np.ndarray  # (3,)
    inertia_O: np.ndarray  # (3,3) about the CoM
    friction: Friction
    physible_points_O: np.ndarray  # (P,3) support points with top-30 % normal impulse
    physible_normals_O: np.ndarray  # (P,3) their outward directions
    residuals: StepResiduals
    loss_history: np.ndarray  # (epochs,)
    support_directions: np.ndarray  # (D,3) unit directions used for mesh export
    support_points: np.ndarray  # (D,3) support points s(d) in O
    metrics: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class ContactConfig:
    """Settings of contact-implicit dynamics learning. ``fast()`` is the reduced preset used by tests.

    Defaults follow PLL / Vysics (method-notes §2.4, §3, §5) except ``width`` (256 in PLL; 64 is enough for
    the convex shapes here and 4-5x faster on CPU) and ``epochs`` (300 in PLL)."""

    seed: int = 0
    # loss weights (PLL defaults)
    w_pred: float = 4.0
    w_comp: float = 1.0
    w_diss: float = 5000.0
    w_pen: float = 0.5
    # penetration weight of the end-effector sphere contact (None: w_pen). The sphere's position is measured by the
    # robot, so a learned surface reaching into it is contradicted by data; with PLL's 0.5 the hidden side of struck
    # objects grew 7-14 mm into the sphere. Off (None) by default: 5 and 50 help the strike sessions but cost on the
    # synthetic pivot session (docs/contact.md, "Strike sessions")
    w_pen_ee: float | None = None
    w_vision: float = 0.04
    w_realizable: float = 1.0  # density realizability of the inertia inside the current geometry (0 = off)
    # prior of the CoM toward the uniform-density centroid of the current hull, (c − ĉ)ᵀA(c − ĉ) with A the shape
    # matrix of the hull's enclosing ellipsoid (0 = off; docs/contact.md, "Centre of mass of strike sessions")
    w_com_centroid: float = 0.0
    # geometry
    geometry: str = "dsf"  # "dsf" deep support function (Vysics) | "polytope" learnable vertices (ContactNets)
    n_vertices: int = 300  # polytope: number of vertices (initialised on the guess / ball)
    width: int = 64  # hidden width W of the deep support function (PLL: 256)
    n_plane: int = 5  # table witness candidates per transition
    export_grid: int = 8  # k of the k×k×k cube-surface direction grid for the mesh (8 -> 296 directions)
    init_radius: float = 0.08  # m, radius of the initial ball when no initial geometry is given
    pretrain_steps: int = 300  # pre-fit of the support function to the initial geometry (0 = random init)
    # inertia / friction
    default_mass: float = 0.37  # kg, used when the mass is not declared
    learn_com: bool = True
    learn_friction: bool = False
    learn_mass: bool = False
    # optimisation
    epochs: int = 300
    batch_size: int = 200
    lr: float = 2e-3  # deep support function weights (PLL)
    lr_inertia: float = 5e-3  # CoM (m per step scale), log-Cholesky moments, friction
    lr_final_fraction: float = 0.05  # cosine decay of both learning rates to this fraction (PLL: constant)
    solver_max_iters: int = 100
    solver_eps_rel: float = 1e-4
    warm_start: bool = True
    patience: int = 25  # stop when the epoch loss has not improved by plateau_rel_tol for this many epochs (0 = off)
    plateau_rel_tol: float = 0.01
    min_epochs: int = 40
    threads: int = 1  # torch threads while the stage runs (restored afterwards; 0 = leave as is)
    max_vision_points: int = 1000  # fixed random subset of V used by the vision term
    closest_candidates: int = 12  # faces tested per point for hull closest points in training (0 = all, exact)
    # physible set
    physible_fraction: float = 0.3
    max_physible_points: int = 20000

    def __post_init__(self):
        if self.geometry not in ("dsf", "polytope"):
            raise ValueError(f"ContactConfig.geometry must be 'dsf' or 'polytope', got {self.geometry!r}")
        for name in ("w_pred", "w_comp", "w_diss", "w_pen", "w_vision", "w_realizable", "w_com_centroid"):
            if not float(getattr(self, name)) >= 0:
                raise ValueError(f"ContactConfig.{name} must be a number >= 0, got {getattr(self, name)!r}")
        if self.w_pen_ee is not None and not float(self.w_pen_ee) >= 0:
            raise ValueError(f"ContactConfig.w_pen_ee must be None or a number >= 0, got {self.w_pen_ee!r}")

    @classmethod
    def tosses(cls, **kw) -> "ContactConfig":
        """Preset for object-only trajectories (tosses): learnable polytope instead of the deep support function and
        penetration weight 50 instead of PLL's 0.5. With 0.5 the loss has a steep wall on the inside of the true
        surface (complementarity) and an almost flat one outside (penetration), and the learned shapes come out
        10-30 % too large. The deep support function learned the real cube with its corners cut (support along
        (1,1,1) 59 mm instead of 91 mm), and the rounded shape rolls in open-loop rollouts (~80° rotation error);
        the polytope gets 85-86 mm and the true cube's rollout error (docs/contact.md)."""
        return cls(**{"w_pen": 50.0, "geometry": "polytope", "w_realizable": 0.0, **kw})

    @classmethod
    def fast(cls) -> "ContactConfig":
        return cls(width=32, epochs=40, pretrain_steps=100, solver_max_iters=100, export_grid=6, min_epochs=20,
                   patience=10, max_vision_points=500)
