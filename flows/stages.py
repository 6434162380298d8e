"""The science stages as the pipeline sees them, and the one generic way to run a stage with caching.

A stage is a ``StageSpec``: the ``service`` module exposing ``run(inputs, cfg, *, progress)``, the output
type (to load it back from the store), the upstream stages it needs and ``build_inputs`` mapping their
outputs (and the session) to the stage's typed inputs. ``run_cached`` computes the key
``sha256(stage, code version, upstream keys, config)``, returns the stored artifact when it exists, and
otherwise runs the stage and stores its output with timings and metrics.

Wiring a new stage = one ``StageSpec`` in ``PIPELINE`` (see docs/architecture.md). Plain Python: the
Prefect task that wraps ``run_cached`` lives in ``flows/pipeline.py``.
"""

from __future__ import annotations

import importlib
import logging
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from service.errors import StageFailed
from service.store import ArtifactRef, ArtifactStore

log = logging.getLogger("vysics.flows")

NOT_AVAILABLE = "stage not available yet"


@dataclass
class StageContext:
    """What ``build_inputs`` sees: the session and lazily loaded upstream outputs."""

    session: Any  # service.session.Session
    store: ArtifactStore
    refs: dict[str, ArtifactRef]
    config: Any = None  # the config of the stage being built
    _values: dict[str, Any] = field(default_factory=dict)

    def value(self, stage: str) -> Any:
        if stage not in self._values:
            spec = STAGES[stage]
            self._values[stage] = self.store.load(spec.output_type(), self.refs[stage])
        return self._values[stage]


@dataclass(frozen=True)
class StageSpec:
    name: str  # stage name = artifact folder = PipelineConfig field
    module: str  # service module exposing run(inputs, cfg, *, progress=None)
    output: str  # "module:Class" of the outputs value
    requires: tuple[str, ...]  # upstream stages (besides the session)
    build_inputs: Callable[[StageContext], Any]
    metrics: Callable[[Any], dict] = lambda out: dict(getattr(out, "metrics", {}) or {})
    # False for stages that only measure (evaluation, residual analysis): when one fails the job still
    # completes with the model, and the report says why that section is empty.
    required: bool = True

    def output_type(self) -> type:
        mod, _, cls = self.output.partition(":")
        return getattr(importlib.import_module(mod), cls)

    def entry_point(self) -> Callable | None:
        try:
            mod = importlib.import_module(self.module)
        except ImportError as e:
            log.warning("stage %s: cannot import %s: %s", self.name, self.module, e)
            return None
        fn = getattr(mod, "run", None)
        return fn if callable(fn) else None

    def unavailable_reason(self) -> str | None:
        """None when the stage can run, else why not (e.g. its ``run`` does not exist yet)."""
        return None if self.entry_point() is not None else NOT_AVAILABLE


# --------------------------------------------------------------------------- input builders
# Each maps upstream outputs to a stage's typed inputs; nothing here reads ground_truth/.


def _tracking_inputs(ctx: StageContext):
    from service.tracking.types import TrackingInputs

    return TrackingInputs(session=ctx.session)


def _contact_inputs(ctx: StageContext):
    """``service.contact.inputs_from_tracking`` (the contact stage's own mapping of tracked poses to its
    state layout; split at lost frames), at the declared mass (None: the contact stage's default)."""
    import service.contact as contact

    s, tr = ctx.session, ctx.value("tracking")
    return contact.inputs_from_tracking(s, tr, tr.visible_points_O, s.mass)


def _fusion_inputs(ctx: StageContext):
    from service.fusion.types import FusionInputs

    tr, co = ctx.value("tracking"), ctx.value("contact")
    return FusionInputs(
        session=ctx.session,
        X_WO=tr.X_WO,
        tracked=tr.tracked,
        visible_sdf=tr.sdf,
        physible_points_O=co.physible_points_O,
        physible_normals_O=co.physible_normals_O,
        physible_mesh=co.physible_mesh,
    )


def _evaluation_inputs(ctx: StageContext):
    from service.bundle import assemble_model
    from service.evaluation.types import EvaluationInputs

    tr, co, fu = ctx.value("tracking"), ctx.value("contact"), ctx.value("fusion")
    meshes = {"vision_only": tr.visible_mesh, "physics_only": co.physible_mesh, "fused": fu.mesh}
    models = {k: assemble_model(ctx.session, co, m) for k, m in meshes.items() if not m.is_empty}
    return EvaluationInputs(session=ctx.session, t=tr.t, X_WO=tr.X_WO, tracked=tr.tracked, meshes=meshes,
                            models=models)


def _residual_inputs(ctx: StageContext):
    from service.bundle import assemble_model
    from service.residuals.types import ObservedTrajectory, ResidualInputs, RobotPath

    s, tr, co, fu = ctx.session, ctx.value("tracking"), ctx.value("contact"), ctx.value("fusion")
    robot = RobotPath(t=np.asarray(s.robot_t, float), p_WE=np.asarray(s.robot_p_WE, float),
                      cmd_WE=None if s.robot_cmd_WE is None else np.asarray(s.robot_cmd_WE, float),
                      radius=float(s.ee_radius))
    return ResidualInputs(
        model=assemble_model(s, co, fu.mesh),
        trajectories=(ObservedTrajectory(t=tr.t, X_WO=tr.X_WO, v_WO_W=tr.v_WO_W, w_WO_O=tr.w_WO_O, tracked=tr.tracked),),
        table_height=float(s.table_height),
        robot=(robot,),
        step_residuals=co.residuals,
    )


PIPELINE: tuple[StageSpec, ...] = (
    StageSpec("tracking", "service.tracking", "service.tracking.types:TrackingOutputs", (), _tracking_inputs),
    StageSpec("contact", "service.contact", "service.contact.types:ContactOutputs", ("tracking",), _contact_inputs),
    StageSpec("fusion", "service.fusion", "service.fusion.types:FusionOutputs", ("tracking", "contact"),
              _fusion_inputs),
    StageSpec("evaluation", "service.evaluation", "service.evaluation.types:EvaluationOutputs",
              ("tracking", "contact", "fusion"), _evaluation_inputs, metrics=lambda out: {}, required=False),
    StageSpec("residuals", "service.residuals", "service.residuals.types:ResidualOutputs",
              ("tracking", "contact", "fusion"), _residual_inputs,
              metrics=lambda out: {"accepted": list(out.accepted), **{f"before_{k}": v for k, v in out.error_before.items()},
                                   **{f"after_{k}": v for k, v in out.error_after.items()}},
              required=False),
)
STAGES: dict[str, StageSpec] = {s.name: s for s in PIPELINE}


def select_stages(selection: str | list[str] | tuple[str, ...] | None) -> tuple[str, ...] | None:
    """Stages to run: None = all; ``"all"``; ``"none"`` (ingest and bundle only); ``"a,b"`` or a list.

    The default comes from ``VYSICS_STAGES``. Unknown names raise ``ValueError``."""
    import os

    if selection is None:
        selection = os.environ.get("VYSICS_STAGES") or "all"
    if isinstance(selection, str):
        text = selection.strip()
        if text in ("", "all"):
            return None
        if text == "none":
            return ()
        selection = [s.strip() for s in text.split(",") if s.strip()]
    unknown = [s for s in selection if s not in STAGES]
    if unknown:
        raise ValueError(f"stages: unknown {unknown}, expected names from {list(STAGES)}, 'all' or 'none'")
    return tuple(selection)


# --------------------------------------------------------------------------- running one stage


@dataclass(frozen=True)
class StageResult:
    ref: ArtifactRef
    cached: bool
    seconds: float  # compute time of the stored artifact (the original run when cached)


def stage_inputs(spec: StageSpec, refs: dict[str, ArtifactRef]) -> dict[str, str]:
    """The input keys of a stage: the ingest artifact of its session, its upstream artifacts, and the code
    version of the module holding its ``build_inputs`` (the mapping is part of what the stage computes)."""
    from service.store import module_code_version

    return {"session": refs["ingest"].key, **{r: refs[r].key for r in spec.requires},
            "wiring": module_code_version(spec.build_inputs.__module__)}


def run_cached(spec: StageSpec, ctx: StageContext, config: Any, *, progress: Callable[[float, str], None] | None = None
               ) -> StageResult:
    """Return the stored output of ``spec`` for these inputs and config, computing it if needed.

    Any exception of the stage becomes ``StageFailed(stage, reason)`` (the traceback is logged)."""
    store = ctx.store
    if ctx.config is None:
        ctx.config = config
    inputs = stage_inputs(spec, ctx.refs)
    key = store.key(spec.name, inputs, config)
    ref = store.get(spec.name, key)
    if ref is not None:
        seconds = float(store.manifest(ref).get("timings_s", {}).get(spec.name, 0.0))
        if progress:
            progress(1.0, "cached")
        return StageResult(ref, True, seconds)
    run = spec.entry_point()
    if run is None:
        raise StageFailed(spec.name, NOT_AVAILABLE)
    try:
        inputs_value = spec.build_inputs(ctx)
        t0 = time.perf_counter()
        out = run(inputs_value, config, progress=progress)
        seconds = time.perf_counter() - t0
        try:
            metrics = spec.metrics(out)
        except Exception:  # noqa: BLE001 - metrics are informative only
            metrics = {}
        ref = store.save(spec.name, key, out, inputs=inputs, config=config, timings={spec.name: seconds},
                         metrics=metrics)
    except StageFailed:
        log.error("stage %s failed\n%s", spec.name, traceback.format_exc())
        raise
    except Exception as e:  # noqa: BLE001 - every failure becomes a job state with stage and reason
        log.error("stage %s failed\n%s", spec.name, traceback.format_exc())
        raise StageFailed(spec.name, f"{type(e).__name__}: {e}") from e
    if progress:
        progress(1.0, "done")
    return StageResult(ref, False, seconds)
