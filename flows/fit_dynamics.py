"""Prefect flow ``fit-dynamics``: contact learning then the residual loop on object trajectories without video.

Thin: each task calls one ``service`` entry point and writes its results into the output folder
(``physible.obj``, ``inertia.json``, ``report.json``, ``report.png`` from contact learning; ``residuals.json``
and ``plots/residuals_*.png`` from the residual loop, whose block also goes into ``report.json``).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
from prefect import flow, task
from prefect.cache_policies import NONE

# Progress callbacks of a running fit, by output folder: set by the caller (the CLI's progress bars), read by
# the tasks. Callables are not flow parameters (Prefect records parameters).
PROGRESS_HOOKS: dict[str, object] = {}


def _progress(out_dir: str, stage: str):
    factory = PROGRESS_HOOKS.get(str(Path(out_dir).resolve()))
    return factory(stage) if callable(factory) else None


def _contact_cfg(preset: str):
    """Toss data has no robot: the contact stage's toss preset, shortened for ``fast``."""
    from service.contact.types import ContactConfig

    cfg = ContactConfig.tosses()
    if preset == "fast":
        fast = ContactConfig.fast()
        cfg = dataclasses.replace(cfg, **{f.name: getattr(fast, f.name) for f in dataclasses.fields(cfg)
                                          if f.name in ("epochs", "steps", "max_epochs") and hasattr(fast, f.name)})
    return cfg


@task(name="contact", cache_policy=NONE, retries=0)
def contact_task(data: str, out_dir: str, preset: str, mass: float | None, train_ids: list[int] | None) -> dict:
    from service.contact import fit_trajectories
    from service.io import save_value

    out, report = fit_trajectories(Path(data), out_dir=Path(out_dir), cfg=_contact_cfg(preset), train_ids=train_ids,
                                   mass=mass, progress=_progress(out_dir, "contact"))
    save_value(out, Path(out_dir) / "artifacts" / "contact")
    return {"train_ids": report["train_ids"]}


@task(name="residuals", cache_policy=NONE, retries=0)
def residuals_task(data: str, out_dir: str, preset: str, train_ids: list[int]) -> dict:
    from service.contact.data import load_trajectories
    from service.contact.types import ContactOutputs
    from service.io import load_value
    from service.residuals import run
    from service.residuals.plots import plot_heldout_errors, plot_rollout_by_mode
    from service.residuals.trajectories import inputs_from_trajectories, learned_model
    from service.residuals.types import ResidualConfig

    out_dir_p = Path(out_dir)
    co = load_value(ContactOutputs, out_dir_p / "artifacts" / "contact")
    trajs, ids, dt, _ = load_trajectories(Path(data))
    keep = set(int(i) for i in train_ids)
    states = [s for s, i in zip(trajs, ids) if int(i) in keep]
    inertia = json.loads((out_dir_p / "inertia.json").read_text())
    model = learned_model(co.physible_mesh, co.mass, bool(inertia.get("mass_declared")), co.com_O, co.inertia_O,
                          co.friction)
    cfg = ResidualConfig.fast() if preset == "fast" else ResidualConfig()
    res = run(inputs_from_trajectories(states, dt, model, step_residuals=co.residuals), cfg,
              progress=_progress(out_dir, "residuals"))
    block = res.report()
    (out_dir_p / "residuals.json").write_text(json.dumps(block, indent=1, allow_nan=False, default=_plain))
    plots = out_dir_p / "plots"
    plot_rollout_by_mode(res, plots / "residuals_by_mode.png")
    plot_heldout_errors(res, plots / "residuals_heldout.png")
    rep_path = out_dir_p / "report.json"
    rep = json.loads(rep_path.read_text())
    rep["residuals"] = block
    rep["model"] = {"effects": dict(res.effects), "friction": dataclasses.asdict(res.model.friction)
                    if res.model is not None else None}
    rep_path.write_text(json.dumps(rep, indent=1, default=_plain))
    return {"accepted": list(res.accepted), "error_before": res.error_before, "error_after": res.error_after}


def _plain(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(type(x).__name__)


@flow(name="fit-dynamics")
def fit_dynamics(data: str, out_dir: str, preset: str = "default", mass: float | None = None,
                 train_ids: list[int] | None = None, residuals: bool = True) -> dict:
    """Learn geometry and inertia from ``data`` (.npz + meta.json), then find and add missing effects."""
    fit = contact_task(data, out_dir, preset, mass, train_ids)
    result = {"contact": fit}
    if residuals:
        result["residuals"] = residuals_task(data, out_dir, preset, fit["train_ids"])
    return result
