"""The library of candidate physical effects the residual loop can add to a fitted model.

Each ``Effect`` is a small physical parameter vector θ (1–3 numbers, bounded) with
- ``signature(stats)``: a scalar computed from the residual statistics by contact mode (``modes.py``)
  that is ≈ 0 when the effect is absent and grows with it (units per effect, see each entry);
- ``guess(stats, model)``: the initial θ read off that signature (the search starts there);
- ``apply(model, θ)``: how θ enters the simulation: either a changed ``ObjectModel`` (friction,
  centre of mass) or keys of the simulator's effect dict (``simulate.py`` documents their meaning);
- ``null``: the value of θ that means "no effect" (the nominal model).

Free-flight kinematics give the gravity, tilt and damping signatures: with backward-difference
velocities the observed acceleration is ``a_k = (v_{k+1} − v_k)/dt``, and in free flight the model
predicts ``a = g`` (and ``ω̇ = −I⁻¹ ω × Iω``, ≈ 0 for the short windows used), so
``mean(a_z)/(−g)`` estimates the gravity scale, ``mean(a_x, a_y)/g`` the tilt, and
``−⟨(a − g)·v⟩/⟨v·v⟩`` the linear damping rate. Impacts give the restitution (ratio of the
normal centre-of-mass speed after/before), rest gives the table offset (mean gap of the lowest model
point to the table while resting), sliding gives the table friction (|tangential deceleration|/g).
Robot-contact and CoM signatures come from the contact stage's unexplained impulse residuals.
Parameter keys (and meanings) follow ``service.sim.effects`` where that registry has them.

Adding an effect = adding one ``Effect`` to ``REGISTRY`` (and, if it needs a new simulator knob,
reading that key in the simulator).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from service.model import ObjectModel
from service.session.types import Friction

G = 9.81
# the parts of the per-frame rollout error an effect can act on (``Effect.component``): |p_sim − p_obs|, ρ·∠(R_obsᵀ R_sim),
# or their sum (the loop's scalar error)
COMPONENTS: tuple[str, ...] = ("position", "rotation", "both")


@dataclass(frozen=True)
class Effect:
    name: str
    params: tuple[str, ...]  # keys, also the keys written to ObjectModel.effects
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    null: tuple[float, ...]
    signature: Callable[[dict], float]
    guess: Callable[[dict, ObjectModel], tuple[float, ...]]
    apply: Callable[[ObjectModel, tuple[float, ...]], tuple[ObjectModel, dict[str, float]]]
    needs_robot: bool = False
    description: str = ""
    resolution: tuple[float, ...] = ()  # smallest physically meaningful change from ``null`` per parameter
    modes: tuple[str, ...] = ("free_flight", "sliding", "robot_contact", "impact", "rest")  # where it acts
    # a uniform horizontal force (tilt): accepted only with its signature, a held-out improvement both on blocks
    # moving downhill and on blocks moving uphill (see loop.direction_check)
    directional: bool = False
    # effects that can explain the same residual (a slide's deceleration: Coulomb friction raised by Δμ and a viscous
    # damping b remove the same energy from a slide launched at v₀ when Δμ ≈ (2/3)·b·v₀/g): with
    # ``ResidualConfig.lookalike_refute`` a passing candidate is rejected when a look-alike predicts the held-out error
    # component both act on better (crossfit.lookalike_refutation)
    lookalikes: tuple[str, ...] = ()
    # the component of the rollout error it acts on (docs/residuals.md §1, "Error where an effect acts"):
    # "position" (a force through the centre of mass: gravity, tilt, table height, linear damping), "rotation" (a
    # torque about it: angular damping), "both" (a force at a contact point off the centre of mass, or a change of
    # where and when the object is touched). Issue #6's "rollout error where it acts" is this component on the
    # frames of ``modes`` of the held-out blocks where it acts (``EffectCandidate.heldout_acting_before/after``)
    component: str = "both"

    def __post_init__(self) -> None:
        if self.component not in COMPONENTS:
            raise ValueError(f"Effect {self.name!r}: component must be one of {COMPONENTS}, not {self.component!r}")

    def clip(self, theta) -> tuple[float, ...]:
        return tuple(float(np.clip(v, lo, hi)) for v, lo, hi in zip(theta, self.lower, self.upper))


def _g(stats: dict, mode: str, key: str, default: float = float("nan")) -> float:
    v = stats.get(mode, {}).get(key)
    return default if v is None or not np.isfinite(v) else float(v)


def _sim_keys(keys: tuple[str, ...]):
    def apply(model: ObjectModel, theta) -> tuple[ObjectModel, dict[str, float]]:
        return model, {k: float(v) for k, v in zip(keys, theta)}

    return apply


def _nz(x: float, default: float = 0.0) -> float:
    return default if not np.isfinite(x) else x


# --- gravity, time scale, tilt ---------------------------------------------------------------------

def _grav_sig(stats):
    return _nz(-_g(stats, "free_flight", "acc_z") / G - 1.0)


def _grav_guess(stats, model):
    return (1.0 + _grav_sig(stats),)


def _time_guess(stats, model):
    return (math.sqrt(max(1.0 + _grav_sig(stats), 1e-3)),)


def _tilt_sig(stats):
    ax, ay = _nz(_g(stats, "free_flight", "acc_x")), _nz(_g(stats, "free_flight", "acc_y"))
    return math.hypot(ax, ay) / G


def _tilt_guess(stats, model):
    ax, ay = _nz(_g(stats, "free_flight", "acc_x")), _nz(_g(stats, "free_flight", "acc_y"))
    az = _g(stats, "free_flight", "acc_z", -G)
    gn = max(math.sqrt(ax * ax + ay * ay + az * az), 1.0)
    tx = math.asin(float(np.clip(ay / gn, -0.5, 0.5)))
    ty = -math.asin(float(np.clip(ax / (gn * math.cos(tx)), -0.5, 0.5)))
    return (tx, ty)


# --- damping ---------------------------------------------------------------------------------------

def _lin_damp_sig(stats):
    return max(_nz(_g(stats, "free_flight", "lin_damping_rate")), 0.0)


def _lin_damp_guess(stats, model):
    return (_lin_damp_sig(stats),)


def _ang_damp_sig(stats):
    return max(_nz(_g(stats, "free_flight", "ang_damping_rate")), 0.0)


def _ang_damp_guess(stats, model):
    return (_ang_damp_sig(stats),)


# --- restitution, table offset ----------------------------------------------------------------------

def _rest_sig(stats):
    return _nz(_g(stats, "impact", "rebound_ratio"))


def _rest_guess(stats, model):
    return (float(np.clip(_rest_sig(stats), 0.0, 0.9)),)


def _table_sig(stats):
    return _nz(_g(stats, "rest", "gap_mean"))


def _table_guess(stats, model):
    return (_table_sig(stats),)


# --- friction --------------------------------------------------------------------------------------

def _fric_table_sig(stats):
    mu = _g(stats, "sliding", "mu_apparent")
    mu0 = _g(stats, "sliding", "mu_model")
    return _nz(mu - mu0)


def _fric_table_guess(stats, model):
    mu = _g(stats, "sliding", "mu_apparent")
    return (float(np.clip(mu if np.isfinite(mu) else model.friction.object_table, 0.02, 1.5)),)


def _fric_robot_sig(stats):
    return _nz(_g(stats, "robot_contact", "res_lin_tangential"))


def _fric_robot_guess(stats, model):
    return (1.0,)


# --- centre of mass --------------------------------------------------------------------------------

def _com_sig(stats):
    vals = [_g(stats, m, "res_ang_norm") for m in ("rest", "robot_contact", "sliding")]
    vals = [v for v in vals if np.isfinite(v)]
    return float(np.mean(vals)) if vals else 0.0


def _com_guess(stats, model):
    return (0.0, 0.0, 0.0)


def _com_apply(model, theta):
    c = np.asarray(model.com_O, float) + np.asarray(theta, float)
    return dataclasses.replace(model, com_O=c), {}


# --- robot clock -----------------------------------------------------------------------------------

def _clock_sig(stats):
    return _nz(_g(stats, "robot_contact", "res_lin_norm"))


def _clock_guess(stats, model):
    return (0.0,)


# --- geometry scale (a correction of a learned model, used as a nuisance parameter) ---------------

def principal_axes(model: ObjectModel) -> np.ndarray:
    """(3,3) columns = principal axes (PCA) of the collision vertices about the CoM, frame O."""
    from service.residuals.modes import collision_vertices

    V = collision_vertices(model) - np.asarray(model.com_O, float)
    _, _, Vt = np.linalg.svd(V - V.mean(0), full_matrices=False)
    P = Vt.T
    if np.linalg.det(P) < 0:
        P[:, 2] = -P[:, 2]
    return P


def scale_model(model: ObjectModel, s) -> ObjectModel:
    """The model with its geometry scaled by s (3,) along its principal axes about the CoM; the inertia
    follows (second moments M = ½ tr(I) 1 − I scale as S M S, I = tr(M) 1 − M), mass and CoM unchanged."""
    s = np.asarray(s, float)
    if np.allclose(s, 1.0):
        return model
    c = np.asarray(model.com_O, float)
    P = principal_axes(model)
    A = P @ np.diag(s) @ P.T

    def sc(m):
        return dataclasses.replace(m, vertices=(np.asarray(m.vertices, float) - c) @ A.T + c)

    I = np.asarray(model.inertia_O, float)
    M = 0.5 * np.trace(I) * np.eye(3) - I
    M2 = A @ M @ A.T
    I2 = np.trace(M2) * np.eye(3) - M2
    return dataclasses.replace(model, visual=sc(model.visual), collision=tuple(sc(m) for m in model.collision),
                               inertia_O=0.5 * (I2 + I2.T))


def _scale_apply(model, theta):
    return scale_model(model, theta), {}


REGISTRY: dict[str, Effect] = {}


def register(effect: Effect) -> Effect:
    REGISTRY[effect.name] = effect
    return effect


register(Effect(
    "gravity_scale", ("gravity_scale",), (0.85,), (1.15,), (1.0,), _grav_sig, _grav_guess,
    _sim_keys(("gravity_scale",)),
    description="|g| = 9.81·s (also absorbs a camera time-scale error: s = time_scale²)",
    resolution=(0.004,),
    modes=("free_flight",),
    component="position",
))
register(Effect(
    "time_scale", ("time_scale",), (0.92,), (1.08,), (1.0,), _grav_sig, _time_guess,
    _sim_keys(("time_scale",)),
    description="physical seconds per data second (camera clock rate error)",
    resolution=(0.002,),
    modes=("free_flight",),
    component="position",
))
register(Effect(
    "table_tilt", ("table_tilt_x", "table_tilt_y"), (-0.15, -0.15), (0.15, 0.15), (0.0, 0.0),
    _tilt_sig, _tilt_guess, _sim_keys(("table_tilt_x", "table_tilt_y")), directional=True,
    description="table tilt = gravity direction in W: g = R_y(ty) R_x(tx) (0,0,-|g|), rad",
    resolution=(0.003, 0.003),
    modes=("free_flight", "sliding", "robot_contact"),
    component="position",
))
register(Effect(
    "table_offset", ("table_offset",), (-0.01,), (0.01,), (0.0,), _table_sig, _table_guess,
    _sim_keys(("table_offset",)),
    description="table surface height error, m (apparent penetration or hovering at rest)",
    resolution=(0.0003,),
    modes=("rest",),
    component="position",
))
register(Effect(
    "restitution", ("restitution",), (0.0,), (0.95,), (0.0,), _rest_sig, _rest_guess,
    _sim_keys(("restitution",)),
    description="coefficient of restitution of the object (table and sphere count 1)",
    resolution=(0.05,),
    modes=("impact", "robot_contact"),  # table impacts, and the sphere's strikes
    component="both",
))
register(Effect(
    "linear_damping", ("linear_damping",), (0.0,), (5.0,), (0.0,), _lin_damp_sig, _lin_damp_guess,
    _sim_keys(("linear_damping",)),
    description="viscous linear damping rate b, 1/s: free motion v(t) = v(0) exp(-b t)",
    resolution=(0.05,),
    modes=("free_flight", "sliding"),
    lookalikes=("friction_table",),
    component="position",
))
register(Effect(
    "angular_damping", ("angular_damping",), (0.0,), (5.0,), (0.0,), _ang_damp_sig, _ang_damp_guess,
    _sim_keys(("angular_damping",)),
    description="viscous angular damping rate b, 1/s: free spin w(t) = w(0) exp(-b t)",
    resolution=(0.05,),
    modes=("free_flight", "sliding"),
    component="rotation",
))
register(Effect(
    "friction_table", ("friction_object_table",), (0.02,), (1.5,), (float("nan"),), _fric_table_sig,
    _fric_table_guess, _sim_keys(("friction_object_table",)),
    description="object-table Coulomb friction replacing the prior",
    resolution=(0.02,),
    modes=("sliding", "robot_contact"),
    lookalikes=("linear_damping",),
    component="both",
))
register(Effect(
    "friction_robot", ("friction_scale_robot",), (0.2,), (5.0,), (1.0,), _fric_robot_sig, _fric_robot_guess,
    _sim_keys(("friction_scale_robot",)), needs_robot=True,
    description="factor on the object-robot Coulomb friction of the prior",
    resolution=(0.1,),
    # the tangential impulse of a glancing strike shows in the free slide that follows (spin, heading): judged on
    # the sliding frames too, as the table friction (on robot-contact frames alone a strike leaves 1-2 frames)
    modes=("robot_contact", "sliding"),
    component="both",
))
register(Effect(
    "com_offset", ("com_offset_x", "com_offset_y", "com_offset_z"), (-0.03,) * 3, (0.03,) * 3, (0.0,) * 3,
    _com_sig, _com_guess, _com_apply,
    description="centre-of-mass shift in O, m (where the CoM was held fixed)",
    resolution=(0.002,) * 3,
    modes=("sliding", "robot_contact"),  # a resting object's pose does not depend on it
    component="both",
))
register(Effect(
    "clock_offset", ("clock_offset",), (-0.2,), (0.2,), (0.0,), _clock_sig, _clock_guess,
    _sim_keys(("clock_offset",)), needs_robot=True,
    description="robot-camera clock offset, s: robot path read at t + delta",
    resolution=(0.005,),
    modes=("robot_contact", "sliding"),
    component="both",
))


register(Effect(
    "geometry_scale", ("geometry_scale_1", "geometry_scale_2", "geometry_scale_3"), (0.5,) * 3, (1.3,) * 3,
    (1.0,) * 3, lambda stats: 0.0, lambda stats, model: (1.0, 1.0, 1.0), _scale_apply,
    description="scale of the learned geometry along its principal axes (a model correction: nuisance only)",
    resolution=(0.02,) * 3,
    modes=("sliding", "rest", "robot_contact"),
    component="both",
))

register(Effect(
    "inertia_scale", ("inertia_scale",), (0.4,), (2.5,), (1.0,), lambda stats: 0.0, lambda stats, model: (1.0,),
    lambda model, th: (dataclasses.replace(model, inertia_O=np.asarray(model.inertia_O, float) * float(th[0])), {}),
    description="factor on the learned rotational inertia (a model correction: nuisance only)",
    resolution=(0.05,),
    modes=("sliding", "rest", "robot_contact"),
    component="both",
))

# Effects that correct the fitted model rather than add physics: refitted first, as nuisance parameters,
# when the model was learned from the same session (never accepted as an effect then).
NUISANCE_LEARNED: tuple[str, ...] = ("geometry_scale", "inertia_scale", "com_offset", "table_offset")
NUISANCE_ONLY: tuple[str, ...] = ("geometry_scale", "inertia_scale")  # never a candidate effect
# effects that act on a free slide through the table contact or the CoM's motion alone, so that they must also show
# on a slide started after the sphere has left the object (release blocks, ``ResidualConfig.release_blocks``), where
# the struck size, the strike's timing and the object-robot contact cannot act
SLIDE_EFFECTS: tuple[str, ...] = ("linear_damping", "angular_damping", "friction_table", "table_tilt")


def is_negligible(effect: Effect, theta, model: ObjectModel) -> bool:
    """True when every parameter is within its resolution of the null value (no physical effect)."""
    null = null_params(effect, model)
    res = effect.resolution or (0.0,) * len(null)
    return all(abs(float(a) - float(b)) <= r for a, b, r in zip(theta, null, res))


def at_bound(effect: Effect, theta, rel: float = 0.02) -> bool:
    """True when a parameter sits on (within ``rel`` of the range of) one of its bounds."""
    return any(min(v - lo, hi - v) <= rel * (hi - lo) for v, lo, hi in zip(theta, effect.lower, effect.upper))


def null_params(effect: Effect, model: ObjectModel) -> tuple[float, ...]:
    """θ meaning 'no effect' for this model (friction effects: the model's current friction)."""
    if effect.name == "friction_table":
        return (float(model.friction.object_table),)
    return effect.null


def fold_into_model(model: ObjectModel, params: dict[str, float], carried: set[str] | None) -> tuple[ObjectModel, dict[str, float]]:
    """The output model of accepted effect parameters ``params`` (flat keys).

    Friction keys become the model's friction (so the URDF carries them), the CoM shift is already in
    ``com_O``; the remaining keys go into ``ObjectModel.effects`` when the simulator registry knows them
    (``carried``; None = all). Returns (model, the keys not carried: effects of the recording).
    """
    f = model.friction
    mu_t = params.get("friction_object_table", f.object_table)
    mu_r = f.object_robot * params.get("friction_scale_robot", 1.0)
    model = dataclasses.replace(model, friction=Friction(object_table=float(mu_t), object_robot=float(mu_r)))
    folded = {"friction_object_table", "friction_scale_robot", "com_offset_x", "com_offset_y", "com_offset_z"}
    eff = dict(model.effects)
    recording: dict[str, float] = {}
    for k, v in params.items():
        if k in folded:
            continue
        if carried is None or k in carried:
            eff[k] = float(v)
        else:
            recording[k] = float(v)
    return dataclasses.replace(model, effects=eff), recording


def apply_effects(model: ObjectModel, chosen: dict[str, tuple[float, ...]]) -> tuple[ObjectModel, dict[str, float]]:
    """Apply several effects: the changed model and the merged simulator effect dict."""
    sim: dict[str, float] = {}
    for name, theta in chosen.items():
        model, extra = REGISTRY[name].apply(model, tuple(theta))
        sim.update(extra)
    return model, sim
