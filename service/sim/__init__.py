"""Open-loop rollout simulator (pybullet): an object model on a table, pushed by a spherical end effector.

Entry point: :func:`rollout`. Effects of ``ObjectModel.effects`` map to simulator settings through the
registry :data:`EFFECTS` (extend it by passing ``effects={**EFFECTS, ...}``).
"""

from service.sim.effects import EFFECTS, EffectSpec, SimSettings, settings_for
from service.sim.rollout import principal_frame, rollout
from service.sim.types import VELOCITY_ONLY_CONTACT, RobotPath, RolloutResult, SimConfig

__all__ = ["EFFECTS", "EffectSpec", "SimSettings", "settings_for", "rollout", "principal_frame",
           "RobotPath", "RolloutResult", "SimConfig", "VELOCITY_ONLY_CONTACT"]
