"""The pipeline configuration: one config per stage, grouped, with named presets.

``PipelineConfig.preset("default")`` uses every stage's defaults; ``"fast"`` uses every stage's ``fast()``
(the reduced settings of tests and demos). ``VYSICS_PRESET`` chooses the preset of the service
(``PipelineConfig.from_settings``). The JSON form (``to_dict`` / ``from_dict``) is what jobs record and what
``--config FILE`` reads: any field left out keeps the preset's value.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from service.contact.types import ContactConfig
from service.evaluation.types import EvaluationConfig
from service.export.types import ExportConfig
from service.fusion.types import FusionConfig
from service.residuals.types import ResidualConfig
from service.tracking.types import TrackingConfig

PRESETS = ("default", "fast")

STAGE_CONFIGS: dict[str, type] = {
    "tracking": TrackingConfig,
    "contact": ContactConfig,
    "fusion": FusionConfig,
    "export": ExportConfig,
    "evaluation": EvaluationConfig,
    "residuals": ResidualConfig,
}


@dataclass(frozen=True)
class PipelineConfig:
    preset: str = "default"
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    contact: ContactConfig = field(default_factory=ContactConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    export: ExportConfig = field(default_factory=ExportConfig)
    evaluation: EvaluationConfig = field(default_factory=EvaluationConfig)
    residuals: ResidualConfig = field(default_factory=ResidualConfig)

    @classmethod
    def preset_named(cls, name: str) -> "PipelineConfig":
        """``default``: every stage's defaults; ``fast``: every stage's ``fast()``."""
        if name == "default":
            return cls(preset="default")
        if name == "fast":
            return cls(preset="fast", **{k: c.fast() for k, c in STAGE_CONFIGS.items()})
        raise ValueError(f"preset {name!r}: expected one of {list(PRESETS)}")

    @classmethod
    def from_settings(cls, settings=None) -> "PipelineConfig":
        """The preset named by ``VYSICS_PRESET`` (``service.settings``)."""
        if settings is None:
            from service.settings import get_settings

            settings = get_settings()
        return cls.preset_named(settings.preset)

    def stage(self, name: str) -> Any:
        """The config of stage ``name`` (``None`` for stages without settings, e.g. ingest)."""
        return getattr(self, name, None) if name in STAGE_CONFIGS else None

    def to_dict(self) -> dict:
        from service.store import _canonical

        return _canonical(self)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1, sort_keys=True)

    @classmethod
    def from_dict(cls, data: dict) -> "PipelineConfig":
        """A preset (``data["preset"]``, default ``"default"``) with the fields given in ``data`` replaced.

        Unknown stages or fields raise ``ValueError`` naming them (a typo must not pass silently)."""
        data = dict(data or {})
        base = cls.preset_named(str(data.pop("preset", "default")))
        changes: dict[str, Any] = {}
        for stage, values in data.items():
            if stage not in STAGE_CONFIGS:
                raise ValueError(f"config: unknown stage {stage!r}, expected one of {list(STAGE_CONFIGS)}")
            if not isinstance(values, dict):
                raise ValueError(f"config.{stage}: expected an object of fields")
            changes[stage] = _replace(getattr(base, stage), values, f"config.{stage}")
        return dataclasses.replace(base, **changes)

    @classmethod
    def from_file(cls, path: Path) -> "PipelineConfig":
        return cls.from_dict(json.loads(Path(path).read_text()))


def _replace(obj: Any, values: dict, where: str) -> Any:
    names = {f.name for f in dataclasses.fields(obj)}
    out: dict[str, Any] = {}
    for k, v in values.items():
        if k not in names:
            raise ValueError(f"{where}: unknown field {k!r}")
        cur = getattr(obj, k)
        if dataclasses.is_dataclass(cur) and isinstance(v, dict):
            out[k] = _replace(cur, v, f"{where}.{k}")
        elif isinstance(cur, tuple) and isinstance(v, list):
            out[k] = tuple(v)
        else:
            out[k] = v
    return dataclasses.replace(obj, **out)
