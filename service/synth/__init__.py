"""Synthetic lab: deterministic synthetic sessions (vysics-session/1) rendered with pybullet.

Entry point ``make_session(spec, out_dir, *, progress=None) -> SynthResult``; see docs/synthetic-lab.md.
"""

from service.synth.generate import describe, make_archive, make_session, sidecar_path
from service.synth.objects import OBJECT_KINDS
from service.synth.types import INTERACTIONS, OCCLUSION_LEVELS, PRESETS, HiddenEffects, SynthResult, SynthSpec

__all__ = [
    "make_session",
    "make_archive",
    "sidecar_path",
    "describe",
    "SynthSpec",
    "SynthResult",
    "HiddenEffects",
    "OBJECT_KINDS",
    "INTERACTIONS",
    "OCCLUSION_LEVELS",
    "PRESETS",
]
