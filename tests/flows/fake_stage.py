"""A tiny stage for store/caching tests: out = inputs.x * cfg.scale, counting its calls."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CALLS = {"n": 0}


@dataclass(frozen=True)
class FakeInputs:
    x: np.ndarray


@dataclass(frozen=True)
class FakeOutputs:
    y: np.ndarray
    metrics: dict


@dataclass(frozen=True)
class FakeConfig:
    scale: float = 2.0
    fail: bool = False


def run(inputs: FakeInputs, cfg: FakeConfig, *, progress=None) -> FakeOutputs:
    CALLS["n"] += 1
    if progress:
        progress(0.5, "halfway")
    if cfg.fail:
        raise RuntimeError("the fake stage was told to fail")
    return FakeOutputs(y=inputs.x * cfg.scale, metrics={"sum": float(np.sum(inputs.x * cfg.scale))})
