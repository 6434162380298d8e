"""The result bundle (format ``vysics-bundle/1``): a folder and a zip of it, from whatever stage outputs exist.

Layout (docs: bundle-format): ``object.urdf`` + ``meshes/collision_*.obj`` + ``meshes/fused.obj`` (written by
``service.export.write_model`` from the final ``ObjectModel``), ``meshes/visible.obj``, ``meshes/physible.obj``,
``trajectory.csv`` (``t,x,y,z,qw,qx,qy,qz`` = X_WO per frame, quaternions with w >= 0), ``report.json``,
``report.html`` (+ ``plots/``). A file whose producer did not run is absent, and ``report.json["bundle"]``
lists the files present and, for each missing one, the reason. Nothing is faked.

The folder is written into a temporary sibling and renamed into place; the zip is written to a temporary
name and renamed, so a reader never sees half a bundle.
"""

from __future__ import annotations

import os
import shutil
import uuid
import zipfile
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from service.mesh import Mesh
from service.model import ObjectModel
from service.report.json import write_report
from service.transforms import pose_to_xyzquat, quat_canonical

FORMAT = "vysics-bundle/1"
REQUIRED_FILES = ("object.urdf", "meshes/fused.obj", "meshes/visible.obj", "meshes/physible.obj",
                  "trajectory.csv", "report.json", "report.html")
MESH_FILES = {"fused": "meshes/fused.obj", "visible": "meshes/visible.obj", "physible": "meshes/physible.obj"}


@dataclass(frozen=True)
class BundleParts:
    """What goes into a bundle. Every part is optional except the report; ``missing[file]`` = why absent."""

    report: dict
    t: np.ndarray | None = None  # (N,) frame times, s
    X_WO: np.ndarray | None = None  # (N,4,4)
    meshes: dict[str, Mesh] = field(default_factory=dict)  # keys of MESH_FILES, frame O
    model: ObjectModel | None = None  # final model -> object.urdf (+ collision pieces, fused.obj)
    export_config: object | None = None  # service.export.ExportConfig
    plots: dict[str, Path] = field(default_factory=dict)  # figures for report.html
    missing: dict[str, str] = field(default_factory=dict)  # file -> reason it is absent


def assemble_model(session, contact, mesh: Mesh, effects: dict | None = None) -> ObjectModel:
    """The ObjectModel of one geometry (``mesh`` in O) with the mass, centre of mass, inertia and friction
    learned by the contact stage (``ContactOutputs``) and the given accepted effects."""
    return ObjectModel(visual=mesh, collision=(), mass=float(contact.mass), mass_declared=session.mass is not None,
                       com_O=np.asarray(contact.com_O, float), inertia_O=np.asarray(contact.inertia_O, float),
                       friction=contact.friction, effects=dict(effects or {}))


def write_trajectory_csv(t: np.ndarray, X_WO: np.ndarray, path: Path) -> Path:
    """``t,x,y,z,qw,qx,qy,qz`` per frame (X_WO), quaternion sign canonical (w >= 0)."""
    t = np.asarray(t, float).reshape(-1)
    X = np.asarray(X_WO, float)
    if X.shape != (len(t), 4, 4):
        raise ValueError(f"trajectory: X_WO must be ({len(t)},4,4) for {len(t)} times, got {X.shape}")
    v = pose_to_xyzquat(X)
    v[:, 3:] = quat_canonical(v[:, 3:])
    rows = np.concatenate([t[:, None], v], 1)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, rows, delimiter=",", fmt="%.9g", header="t,x,y,z,qw,qx,qy,qz", comments="")
    return path


def _write_html(report: dict, plots: dict[str, Path], folder: Path) -> None:
    from service.report.html import write_html

    write_html(report, plots, folder)


def _fill(parts: BundleParts, folder: Path) -> dict:
    present: list[str] = []
    missing = dict(parts.missing)
    if parts.model is not None:
        from service.export import write_model

        write_model(parts.model, folder, parts.export_config)
        present.append("object.urdf")
        present += sorted(p.relative_to(folder).as_posix() for p in (folder / "meshes").glob("collision_*.obj"))
        present.append(MESH_FILES["fused"])
    for name, rel in MESH_FILES.items():
        if rel in present:
            continue
        mesh = parts.meshes.get(name)
        if mesh is not None and not mesh.is_empty:
            mesh.save_obj(folder / rel)
            present.append(rel)
    if parts.t is not None and parts.X_WO is not None:
        write_trajectory_csv(parts.t, parts.X_WO, folder / "trajectory.csv")
        present.append("trajectory.csv")
    present += ["report.json", "report.html"]
    for rel in REQUIRED_FILES:
        if rel not in present:
            missing.setdefault(rel, "stage not available yet")
        else:
            missing.pop(rel, None)
    report = dict(parts.report)
    report["bundle"] = {"format": FORMAT, "files": sorted(present), "missing": dict(sorted(missing.items()))}
    write_report(report, folder / "report.json")
    _write_html(report, parts.plots, folder)
    return report


def zip_folder(folder: Path, zip_path: Path) -> Path:
    """Zip ``folder``'s files at the archive root (sorted names, fixed timestamps: same files, same zip)."""
    folder, zip_path = Path(folder), Path(zip_path)
    zip_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = zip_path.with_name(f".{zip_path.name}.{uuid.uuid4().hex[:8]}.part")
    try:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as z:
            for p in sorted(q for q in folder.rglob("*") if q.is_file()):
                info = zipfile.ZipInfo(p.relative_to(folder).as_posix(), date_time=(2020, 1, 1, 0, 0, 0))
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = 0o644 << 16
                z.writestr(info, p.read_bytes())
        os.replace(tmp, zip_path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return zip_path


def _swap_into_place(tmp: Path, out_dir: Path) -> None:
    """Rename the finished folder ``tmp`` to ``out_dir``, replacing a previous bundle there (never a folder
    that holds something else)."""
    if out_dir.exists():
        if not out_dir.is_dir():
            raise FileExistsError(f"{out_dir}: exists and is not a folder")
        if any(out_dir.iterdir()) and not (out_dir / "report.json").is_file():
            raise FileExistsError(f"{out_dir}: exists, is not empty and holds no bundle; refusing to replace it")
        old = out_dir.with_name(f".{out_dir.name}.{uuid.uuid4().hex[:8]}.old")
        os.rename(out_dir, old)
        os.rename(tmp, out_dir)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.rename(tmp, out_dir)


def write_bundle(parts: BundleParts, out_dir: Path, *, zip_path: Path | None = None) -> dict:
    """Write the bundle folder ``out_dir`` (replacing a previous bundle there) and, if asked, its zip.

    Returns the report as written (with its ``bundle`` section)."""
    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = out_dir.with_name(f".{out_dir.name}.{uuid.uuid4().hex[:8]}.tmp")
    tmp.mkdir()
    try:
        report = _fill(parts, tmp)
        if zip_path is not None:
            zip_folder(tmp, Path(zip_path))
        _swap_into_place(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return report


def copy_bundle(src: Path, out_dir: Path) -> Path:
    """Copy a written bundle folder to ``out_dir`` (same replace rules as :func:`write_bundle`)."""
    src, out_dir = Path(src), Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = out_dir.with_name(f".{out_dir.name}.{uuid.uuid4().hex[:8]}.tmp")
    shutil.copytree(src, tmp)
    try:
        _swap_into_place(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out_dir


def _stage_figures(session, tracking, residuals, plots_dir: Path) -> dict[str, Path]:
    """Figures of the stages themselves: the visible mesh over a few frames, velocities, residuals before and
    after. A figure that fails is left out (and logged); it never costs the bundle."""
    import logging

    log = logging.getLogger("vysics.bundle")
    figs: dict[str, Path] = {}
    plots_dir.mkdir(parents=True, exist_ok=True)
    jobs = []
    if tracking is not None:
        from service.tracking import plots as tp

        jobs += [("mesh_overlay", lambda p: tp.overlay_frames(session, tracking, path=p)),
                 ("velocities", lambda p: tp.velocity_figure(tracking, path=p))]
    if residuals is not None:
        from service.residuals import plots as rp

        jobs += [("residuals_by_mode", lambda p: rp.plot_rollout_by_mode(residuals, p)),
                 ("residuals_heldout", lambda p: rp.plot_heldout_errors(residuals, p)),
                 ("residuals_steps", lambda p: rp.plot_step_residuals(residuals, p))]
    for name, make in jobs:
        path = plots_dir / f"{name}.png"
        try:
            make(path)
            if path.exists():
                figs[name] = path
        except Exception as e:  # noqa: BLE001 - figures must not cost the bundle
            log.warning("figure %s failed: %s: %s", name, type(e).__name__, e)
        finally:
            import matplotlib.pyplot as plt

            plt.close("all")
    return figs


def parts_from_outputs(
    *,
    session,
    outputs: dict,
    timings_s: dict[str, float | None],
    reasons: dict[str, str],
    export_config=None,
    plots_dir: Path | None = None,
) -> BundleParts:
    """Assemble the bundle from stage outputs (keys: tracking, contact, fusion, evaluation, residuals; any
    may be missing). The final model needs contact (inertia, friction) and fusion (geometry); residual
    effects that were accepted go into it. ``reasons[stage]`` explains a missing stage."""
    from service.report.json import build_report

    tr, co, fu = outputs.get("tracking"), outputs.get("contact"), outputs.get("fusion")
    ev, rs = outputs.get("evaluation"), outputs.get("residuals")
    meshes: dict[str, Mesh] = {}
    missing: dict[str, str] = {}
    if tr is not None:
        meshes["visible"] = tr.visible_mesh
    else:
        missing["trajectory.csv"] = missing["meshes/visible.obj"] = f"tracking: {reasons.get('tracking', 'did not run')}"
    if co is not None:
        meshes["physible"] = co.physible_mesh
    else:
        missing["meshes/physible.obj"] = f"contact: {reasons.get('contact', 'did not run')}"
    if fu is not None:
        meshes["fused"] = fu.mesh
    else:
        missing["meshes/fused.obj"] = f"fusion: {reasons.get('fusion', 'did not run')}"
    model = None
    model_reason = None
    if co is not None and fu is not None and not fu.mesh.is_empty:
        model = assemble_model(session, co, fu.mesh, rs.effects if rs is not None else None)
        augmented = getattr(rs, "model", None) if rs is not None else None
        if augmented is not None:
            # the residual loop may also have changed friction or the centre of mass (accepted effects)
            model = replace(model, friction=augmented.friction, com_O=np.asarray(augmented.com_O, float))
    else:
        model_reason = next((f"{s}: {reasons[s]}" for s in ("contact", "fusion") if s in reasons),
                            "needs contact and fusion outputs")
        missing["object.urdf"] = model_reason
    plots: dict[str, Path] = {}
    if ev is not None and plots_dir is not None:
        try:
            from service.report.plots import make_plots

            named = {"vision_only": meshes.get("visible"), "physics_only": meshes.get("physible"),
                     "fused": meshes.get("fused")}
            plots = make_plots(ev.series, {k: m for k, m in named.items() if m is not None}, Path(plots_dir))
        except Exception as e:  # noqa: BLE001 - figures must not cost the bundle
            reasons = {**reasons, "plots": f"figures failed: {type(e).__name__}: {e}"}
    if plots_dir is not None:
        plots.update(_stage_figures(session, tr, rs, Path(plots_dir)))
    rsn = {"model": model_reason} if model_reason else {}
    for s in ("tracking", "evaluation", "residuals"):
        if outputs.get(s) is None:
            rsn[s] = reasons.get(s, "did not run")
    report = build_report(
        session={"name": session.name, "sha256": session.sha256, "frames": int(session.n_frames)},
        timings_s=timings_s, model=model, tracking=tr, evaluation=ev, residuals=rs, reasons=rsn,
        extra={"stages": {s: {"ran": outputs.get(s) is not None, **({"reason": reasons[s]} if s in reasons else {})}
                          for s in dict.fromkeys(("tracking", "contact", "fusion", "evaluation", "residuals",
                                                  *outputs, *reasons))}},
    )
    t = X = None
    if tr is not None:
        t, X = tr.t, tr.X_WO
    return BundleParts(report=report, t=t, X_WO=X, meshes=meshes, model=model, export_config=export_config,
                       plots=plots, missing=missing)
