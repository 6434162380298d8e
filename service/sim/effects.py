"""Named physical effects and how each one changes the simulator settings.

An object model carries its accepted effects as ``ObjectModel.effects`` (name -> one float). Each
name maps to an :class:`EffectSpec` whose ``apply(settings, value)`` returns new
:class:`SimSettings`. The built-in table is :data:`EFFECTS`; code that proposes new effects extends it
without touching this module by passing ``{**EFFECTS, "name": EffectSpec(...)}`` as ``effects`` to
:func:`service.sim.rollout`.

Built-in effects (units SI):
- ``restitution`` e ∈ [0, 1]: coefficient of restitution of the object (table and robot contacts).
- ``linear_damping``, ``angular_damping`` b (1/s): viscous decay, free motion ``v(t) = v(0) e^{−b t}``
  (applied as a force −m b v at the CoM and a torque −b I ω; Bullet's own damping is off).
- ``table_tilt_x``, ``table_tilt_y`` (rad): gravity rotated about W's x / y axis, which is the same as the
  table plane tilted the other way (the table stays z = table_height in the simulated world).
- ``clock_offset`` (s): the robot path is replayed as ``p_E(t + clock_offset)``.
- ``spinning_friction``, ``rolling_friction`` (m): torsional and rolling resistance at the table contact.
- ``contact_stiffness`` (N/m) with optional ``contact_damping`` (N s/m): compliant table contact.
- ``friction_scale_table``, ``friction_scale_robot``: multiply the model's friction coefficients.
- ``friction_object_table``: replaces the model's object–table coefficient.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Callable, Mapping

import numpy as np

from service.transforms import so3_exp

G = 9.81


@dataclass(frozen=True)
class SimSettings:
    """Everything an effect may change; the defaults are the plain rigid-body model."""

    gravity_W: tuple[float, float, float] = (0.0, 0.0, -G)
    restitution: float = 0.0
    linear_damping: float = 0.0
    angular_damping: float = 0.0
    clock_offset: float = 0.0
    spinning_friction: float = 0.0
    rolling_friction: float = 0.0
    contact_stiffness: float | None = None
    contact_damping: float | None = None
    friction_scale_table: float = 1.0
    friction_scale_robot: float = 1.0
    friction_object_table: float | None = None  # absolute override of the model's value
    extra: dict[str, float] = field(default_factory=dict)  # free slots for effects defined elsewhere


@dataclass(frozen=True)
class EffectSpec:
    apply: Callable[[SimSettings, float], SimSettings]
    description: str
    default: float = 0.0  # value at which the effect does nothing
    bounds: tuple[float, float] = (-np.inf, np.inf)


def _tilt(axis: int) -> Callable[[SimSettings, float], SimSettings]:
    def apply(s: SimSettings, angle: float) -> SimSettings:
        r = np.zeros(3)
        r[axis] = angle
        g = so3_exp(r) @ np.asarray(s.gravity_W, float)
        return replace(s, gravity_W=tuple(float(x) for x in g))

    return apply


def _field(name: str) -> Callable[[SimSettings, float], SimSettings]:
    return lambda s, v: replace(s, **{name: float(v)})


def _positive_or_none(name: str) -> Callable[[SimSettings, float], SimSettings]:
    return lambda s, v: replace(s, **{name: float(v) if v > 0 else None})


def _scale(name: str) -> Callable[[SimSettings, float], SimSettings]:
    return lambda s, v: replace(s, **{name: getattr(s, name) * float(v)})


EFFECTS: Mapping[str, EffectSpec] = MappingProxyType(
    {
        "restitution": EffectSpec(_field("restitution"), "coefficient of restitution of the object", 0.0, (0.0, 1.0)),
        "linear_damping": EffectSpec(_field("linear_damping"), "viscous linear damping rate, 1/s", 0.0, (0.0, 20.0)),
        "angular_damping": EffectSpec(_field("angular_damping"), "viscous angular damping rate, 1/s", 0.0, (0.0, 20.0)),
        "table_tilt_x": EffectSpec(_tilt(0), "gravity rotated about W x, rad", 0.0, (-0.2, 0.2)),
        "table_tilt_y": EffectSpec(_tilt(1), "gravity rotated about W y, rad", 0.0, (-0.2, 0.2)),
        "clock_offset": EffectSpec(_field("clock_offset"), "robot path replayed at t + offset, s", 0.0, (-0.2, 0.2)),
        "spinning_friction": EffectSpec(_field("spinning_friction"), "torsional friction at the table, m", 0.0, (0.0, 0.05)),
        "rolling_friction": EffectSpec(_field("rolling_friction"), "rolling friction at the table, m", 0.0, (0.0, 0.05)),
        "contact_stiffness": EffectSpec(_positive_or_none("contact_stiffness"), "compliant table contact, N/m", 0.0, (1e2, 1e7)),
        "contact_damping": EffectSpec(_positive_or_none("contact_damping"), "compliant table contact damping, N s/m", 0.0, (0.0, 1e5)),
        "friction_scale_table": EffectSpec(_scale("friction_scale_table"), "x object-table friction", 1.0, (0.1, 5.0)),
        "friction_object_table": EffectSpec(_field("friction_object_table"), "object-table friction", 0.26, (0.0, 2.0)),
        "friction_scale_robot": EffectSpec(_scale("friction_scale_robot"), "x object-robot friction", 1.0, (0.1, 5.0)),
    }
)


def settings_for(effects: Mapping[str, float], registry: Mapping[str, EffectSpec] | None = None) -> SimSettings:
    """Apply named effects (in a fixed, sorted order) to the plain settings.

    Raises ``ValueError`` naming an effect that the registry does not know.
    """
    registry = EFFECTS if registry is None else registry
    s = SimSettings()
    for name in sorted(effects):
        if name not in registry:
            raise ValueError(f"unknown effect {name!r}; known: {sorted(registry)}")
        s = registry[name].apply(s, float(effects[name]))
    return s
