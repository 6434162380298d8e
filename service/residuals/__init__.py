"""Residual loop: what the fitted model fails to explain, which physical effect explains it, before/after.

Entry point: ``run(ResidualInputs, ResidualConfig, *, progress=None) -> ResidualOutputs`` (``loop.py``).
Effects library: ``effects.REGISTRY``; contact modes: ``modes.py``; built-in simulator: ``simulate.py``;
plots: ``plots.py``. Method: docs/residuals.md.
"""

from service.residuals.loop import run

__all__ = ["run"]
