"""Fusion: second SDF pass with vision depth terms and contact-induced (physible) terms."""

from service.fusion.stage import fuse, run, session_rays
from service.fusion.types import FusionConfig, FusionInputs, FusionOutputs, LossWeights, SampleExtents

__all__ = ["FusionConfig", "FusionInputs", "FusionOutputs", "LossWeights", "SampleExtents", "fuse", "run", "session_rays"]
