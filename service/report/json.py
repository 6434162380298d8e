"""``report.json`` (format ``vysics-report/1``): every key of docs bundle-format, from whatever stages ran.

``build_report`` fills each section from the outputs it is given; a section whose producer did not run
keeps every key with ``null`` values and a ``reason`` (the convention of the evaluation stage: ``reason``
for a whole block, ``<metric>_reason`` for one metric). ``write_report`` writes it as strict JSON
(NaN and infinities become ``null``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

FORMAT = "vysics-report/1"
TIMED_STAGES = ("ingest", "tracking", "contact", "fusion", "evaluation", "residuals")
METHODS_GEOMETRY = ("vision_only", "physics_only", "fused")
METHODS_DYNAMICS = ("vision_only", "physics_only", "fused", "ground_truth_geometry")
DYNAMICS_KEYS = ("pos_err_m", "rot_err_deg", "time_before_divergence_s", "contact_iou")
NOT_AVAILABLE = "stage not available yet"


def plain(x: Any) -> Any:
    """JSON-safe copy: numpy to Python, tuples to lists, non-finite floats to None."""
    if isinstance(x, dict):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return plain(x.tolist())
    if isinstance(x, (np.bool_,)):
        return bool(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, Path):
        return str(x)
    return x


def _null_block(keys, reason: str) -> dict:
    return {**{k: None for k in keys}, "reason": reason}


def model_section(model, reason: str | None) -> dict:
    """``model``: the final ObjectModel (``service.model.ObjectModel``) or nulls with ``reason``."""
    if model is None:
        return {"mass_kg": None, "mass_declared": None, "com_O": None, "inertia_O": None,
                "friction": {"object_table": None, "object_robot": None}, "effects": {},
                "reason": reason or NOT_AVAILABLE}
    out = {
        "mass_kg": float(model.mass),
        "mass_declared": bool(model.mass_declared),
        "com_O": plain(np.asarray(model.com_O, float)),
        "inertia_O": plain(np.asarray(model.inertia_O, float)),
        "friction": {"object_table": float(model.friction.object_table),
                     "object_robot": float(model.friction.object_robot)},
        "effects": {k: float(v) for k, v in (model.effects or {}).items()},
    }
    if not model.mass_declared:
        out["mass_kg_reason"] = "mass not declared in session.json: default mass (not identifiable from kinematics)"
    return out


def tracking_section(tracking, evaluation, reason: str | None, eval_reason: str | None) -> dict:
    """``tracking``: counts from the tracking outputs, ``vs_ground_truth`` from evaluation."""
    if tracking is None:
        out = {"frames_tracked": None, "frames_lost": None, "reason": reason or NOT_AVAILABLE}
    else:
        tracked = np.asarray(tracking.tracked, bool)
        out = {"frames_tracked": int(tracked.sum()), "frames_lost": int(tracking.frames_lost)}
        strip = getattr(tracking, "mask_strip_fraction", None)
        out["masks"] = {"trimmed_by_colour": bool(getattr(tracking, "masks_trimmed", False)),
                        "strip_fraction": None if strip is None else float(strip)}
    if evaluation is not None:
        out["vs_ground_truth"] = plain(evaluation.tracking) if evaluation.tracking is not None else None
    else:
        out["vs_ground_truth"] = None
        out["vs_ground_truth_reason"] = eval_reason or NOT_AVAILABLE
    return out


def geometry_section(evaluation, reason: str | None) -> dict | None:
    if evaluation is not None:
        return plain(evaluation.geometry)
    return {m: _null_block(("chamfer_m", "iou"), reason or NOT_AVAILABLE) for m in METHODS_GEOMETRY}


def dynamics_section(evaluation, reason: str | None) -> dict:
    if evaluation is not None:
        return plain(evaluation.dynamics)
    return {m: _null_block(DYNAMICS_KEYS, reason or NOT_AVAILABLE) for m in METHODS_DYNAMICS}


def residuals_section(residuals, reason: str | None) -> dict:
    if residuals is None:
        return {"candidates": [], "accepted": [],
                "error_before": {"pos_err_m": None, "rot_err_deg": None},
                "error_after": {"pos_err_m": None, "rot_err_deg": None},
                "reason": reason or NOT_AVAILABLE}
    return plain({
        "candidates": [
            {"effect": c.effect, "params": dict(c.params), "heldout_error_before": c.heldout_error_before,
             "heldout_error_after": c.heldout_error_after, "accepted": bool(c.accepted),
             **({"reason": c.reason} if c.reason else {}),
             # where the effect acts (contact modes, error component) and the held-out error there before/after
             # (docs/residuals.md §1): issue #6's "rollout error where it acts"
             **({"acts_on": dict(c.acts_on), "heldout_acting_before": c.heldout_acting_before,
                 "heldout_acting_after": c.heldout_acting_after} if getattr(c, "acts_on", None) else {})}
            for c in residuals.candidates
        ],
        "accepted": list(residuals.accepted),
        "error_before": dict(residuals.error_before),
        "error_after": dict(residuals.error_after),
        **({"by_mode": residuals.by_mode} if residuals.by_mode else {}),
        # accepted effects of the recording itself (gravity/time scale, table offset): reported, not simulated
        "recording_effects": dict(getattr(residuals, "recording_effects", {}) or {}),
        # nuisance corrections of the learned model the effects were judged against: reported, not in the model
        "corrections": dict(getattr(residuals, "corrections", {}) or {}),
    })


def build_report(
    *,
    session: dict,
    timings_s: dict[str, float | None],
    model=None,
    tracking=None,
    evaluation=None,
    residuals=None,
    reasons: dict[str, str] | None = None,
    extra: dict | None = None,
) -> dict:
    """The report dict.

    ``session``: ``{"name", "sha256", "frames"}``. ``timings_s``: seconds per stage that ran (others become
    ``null``); ``total`` is their sum unless given. ``model``: ``ObjectModel`` or None; ``tracking``:
    ``TrackingOutputs``; ``evaluation``: ``EvaluationOutputs``; ``residuals``: ``ResidualOutputs``.
    ``reasons[section]`` says why a missing section is missing (default: "stage not available yet").
    """
    reasons = dict(reasons or {})
    tim: dict[str, float | None] = {s: None for s in TIMED_STAGES}
    tim.update({k: (None if v is None else float(v)) for k, v in timings_s.items()})
    if tim.get("total") is None:
        tim["total"] = float(sum(v for k, v in tim.items() if k != "total" and v is not None))
    report = {
        "format": FORMAT,
        "session": {"name": session.get("name"), "sha256": session.get("sha256"), "frames": session.get("frames")},
        "timings_s": tim,
        "model": model_section(model, reasons.get("model")),
        "tracking": tracking_section(tracking, evaluation, reasons.get("tracking"), reasons.get("evaluation")),
        "geometry": geometry_section(evaluation, reasons.get("evaluation")),
        "dynamics": dynamics_section(evaluation, reasons.get("evaluation")),
        "residuals": residuals_section(residuals, reasons.get("residuals")),
    }
    if extra:
        report.update(plain(extra))
    return plain(report)


REQUIRED_KEYS = {
    "format": None,
    "session": ("name", "sha256", "frames"),
    "timings_s": TIMED_STAGES + ("total",),
    "model": ("mass_kg", "mass_declared", "com_O", "inertia_O", "friction", "effects"),
    "tracking": ("frames_tracked", "frames_lost", "vs_ground_truth"),
    "geometry": None,
    "dynamics": None,
    "residuals": ("candidates", "accepted", "error_before", "error_after"),
}


def missing_keys(report: dict) -> list[str]:
    """Keys required by the bundle format that ``report`` lacks (empty list = complete)."""
    out = []
    for k, sub in REQUIRED_KEYS.items():
        if k not in report:
            out.append(k)
            continue
        if sub and isinstance(report[k], dict):
            out += [f"{k}.{s}" for s in sub if s not in report[k]]
    return out


def write_report(report: dict, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(plain(report), indent=1, allow_nan=False))
    return path
