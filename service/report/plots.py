"""Report figures (matplotlib, Agg canvas, no pyplot state): trajectories, errors over time, divergence
curves, contact timelines and renders of the estimated meshes against the true shape.

``make_plots(series, meshes, out_dir)`` takes the ``series`` of ``service.evaluation`` outputs and the
meshes in O, writes PNG files into ``out_dir`` and returns ``{name: path}``. Every figure is optional: a
figure whose data is missing is simply not produced.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from service.mesh import Mesh

COLORS = {"tracked": "#222222", "vision_only": "#d62728", "physics_only": "#1f77b4", "fused": "#2ca02c",
          "ground_truth_geometry": "#9467bd", "ground_truth": "#7f7f7f"}
LABELS = {"vision_only": "vision only", "physics_only": "physics only", "fused": "fused (Vysics)",
          "ground_truth_geometry": "true geometry", "tracked": "tracked"}
METHOD_ORDER = ("vision_only", "physics_only", "fused", "ground_truth_geometry")


def _figure(w: float, h: float, **adjust):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h), dpi=100)
    FigureCanvasAgg(fig)
    fig.subplots_adjust(**{"left": 0.08, "right": 0.98, "bottom": 0.14, "top": 0.9, "wspace": 0.25, **adjust})
    return fig


def _save(fig, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)  # fixed margins (no tight layout: it draws the figure twice)
    return path


def _methods(series: dict, suffix: str) -> list[str]:
    found = {k.split("/")[1] for k in series if k.startswith("dynamics/") and k.endswith("/" + suffix)}
    return [m for m in METHOD_ORDER if m in found] + sorted(found - set(METHOD_ORDER))


def plot_trajectories(series: dict, path: Path) -> Path | None:
    if "dynamics/t" not in series:
        return None
    t = series["dynamics/t"]
    fig = _figure(10, 4)
    ax1, ax2 = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    tr = series.get("dynamics/tracked_p_WO")
    if tr is not None:
        ax1.plot(tr[:, 0], tr[:, 1], color=COLORS["tracked"], lw=2.5, label="tracked")
        ax2.plot(t, tr[:, 2], color=COLORS["tracked"], lw=2.5, label="tracked")
    for m in _methods(series, "p_WO"):
        p = series[f"dynamics/{m}/p_WO"]
        c = COLORS.get(m)
        ax1.plot(p[:, 0], p[:, 1], color=c, lw=1.3, label=LABELS.get(m, m))
        ax2.plot(t, p[:, 2], color=c, lw=1.3, label=LABELS.get(m, m))
    ax1.set(xlabel="x (m)", ylabel="y (m)", title="object position, top view")
    if tr is not None and np.isfinite(tr[:, :2]).any():
        # frame the tracked motion (a rollout that runs away leaves the frame instead of shrinking it)
        lo, hi = np.nanmin(tr[:, :2], 0), np.nanmax(tr[:, :2], 0)
        c, half = 0.5 * (lo + hi), max(0.15, 0.75 * float((hi - lo).max()))
        ax1.set(xlim=(c[0] - half, c[0] + half), ylim=(c[1] - half, c[1] + half))
        ax1.set_aspect("equal", adjustable="box")
    else:
        ax1.set_aspect("equal", adjustable="datalim")
    ax2.set(xlabel="t (s)", ylabel="z (m)", title="object height")
    ax1.legend(fontsize=8)
    return _save(fig, path)


def plot_errors(series: dict, path: Path, div_pos: float = 0.10, div_rot_deg: float = 45.0) -> Path | None:
    ms = _methods(series, "pos_err_m")
    if not ms:
        return None
    t = series["dynamics/t"]
    fig = _figure(10, 4)
    ax1, ax2 = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    for m in ms:
        ax1.plot(t, series[f"dynamics/{m}/pos_err_m"], color=COLORS.get(m), label=LABELS.get(m, m))
        ax2.plot(t, series[f"dynamics/{m}/rot_err_deg"], color=COLORS.get(m), label=LABELS.get(m, m))
    ax1.axhline(div_pos, color="k", ls="--", lw=0.8)
    ax2.axhline(div_rot_deg, color="k", ls="--", lw=0.8)
    ax1.set(xlabel="t (s)", ylabel="position error (m)", title="open-loop rollout vs tracked")
    ax2.set(xlabel="t (s)", ylabel="rotation error (deg)", title="open-loop rollout vs tracked")
    ax1.legend(fontsize=8)
    return _save(fig, path)


def plot_contacts(series: dict, path: Path) -> Path | None:
    ms = _methods(series, "contact")
    if not ms:
        return None
    t = series["dynamics/t"]
    rows = ([("annotated", series["dynamics/annotated_contact"], COLORS["ground_truth"])]
            if "dynamics/annotated_contact" in series else [])
    rows += [(LABELS.get(m, m), series[f"dynamics/{m}/contact"], COLORS.get(m)) for m in ms]
    h = 0.9 + 0.4 * len(rows)
    fig = _figure(10, h, left=0.16, bottom=0.55 / h, top=1 - 0.35 / h)
    ax = fig.add_subplot(1, 1, 1)
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.033
    for i, (name, on, c) in enumerate(rows):
        on = np.asarray(on, bool)
        ax.broken_barh([(ti - dt / 2, dt) for ti in t[on]], (i - 0.35, 0.7), color=c)
    ax.set_yticks(range(len(rows)), [r[0] for r in rows])
    ax.set(xlabel="t (s)", title="robot-object contact", xlim=(t[0], t[-1] + dt))
    ax.invert_yaxis()
    return _save(fig, path)


def plot_tracking(series: dict, path: Path) -> Path | None:
    if "tracking/trans_err_m" not in series:
        return None
    t = series.get("dynamics/t")
    e_t, e_r = series["tracking/trans_err_m"], series["tracking/rot_err_deg"]
    x = np.arange(len(e_t)) if t is None or len(t) != len(e_t) else t
    fig = _figure(10, 3)
    ax1, ax2 = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    ax1.plot(x, 1000 * e_t, color="k")
    ax2.plot(x, e_r, color="k")
    ax1.set(xlabel="t (s)" if x is t else "frame", ylabel="translation error (mm)", title="tracking vs ground truth")
    ax2.set(xlabel="t (s)" if x is t else "frame", ylabel="rotation error (deg)", title="tracking vs ground truth")
    return _save(fig, path)


def divergence_curves(times_frac: dict[str, list[float]], path: Path, title: str = "") -> Path | None:
    """Fraction of rollouts still within the divergence thresholds vs normalised time (paper Fig. 'CDF').

    ``times_frac``: method -> time-before-divergence / trajectory length, one value per session."""
    if not any(times_frac.values()):
        return None
    fig = _figure(6, 4)
    ax = fig.add_subplot(1, 1, 1)
    s = np.linspace(0, 1, 201)
    for m, v in times_frac.items():
        v = np.asarray([x for x in v if x is not None], float)
        if len(v) == 0:
            continue
        alive = (v[None, :] >= s[:, None] - 1e-12).mean(1)
        ax.step(s, alive, where="post", color=COLORS.get(m), label=f"{LABELS.get(m, m)} (n={len(v)})")
    ax.set(xlabel="fraction of the trajectory", ylabel="fraction of rollouts not diverged", ylim=(-0.02, 1.02),
           title=title or "time before divergence (0.10 m / 45°)")
    ax.legend(fontsize=8)
    return _save(fig, path)


def _draw_mesh(ax, mesh: Mesh, color: str, alpha: float, max_faces: int) -> None:
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    v = np.asarray(mesh.vertices, float)
    f = np.asarray(mesh.faces, np.int64)
    if len(f) > max_faces:  # display only: keep a deterministic subset of the faces
        f = f[np.linspace(0, len(f) - 1, max_faces).astype(int)]
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    shade = 0.45 + 0.55 * np.clip(n @ np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8]), 0, 1)
    from matplotlib.colors import to_rgb

    rgb = np.asarray(to_rgb(color))
    col = np.c_[shade[:, None] * rgb[None, :], np.full(len(f), alpha)]
    ax.add_collection3d(Poly3DCollection(tri, facecolors=col, edgecolors="none"))


def plot_meshes(meshes: dict[str, Mesh], truth: Mesh | None, path: Path, max_faces: int = 5000) -> Path | None:
    """One 3D panel per method: the estimate (coloured) with the true shape as grey points."""
    names = [m for m in METHOD_ORDER if m in meshes and meshes[m] is not None and not meshes[m].is_empty]
    if not names:
        return None
    from service.evaluation.geometry import sample_surface

    fig = _figure(4 * len(names), 4.2, left=0.0, right=1.0, bottom=0.02, top=0.92, wspace=0.05)
    allv = np.concatenate([np.asarray(meshes[m].vertices) for m in names]
                          + ([np.asarray(truth.vertices)] if truth is not None else []))
    c, r = 0.5 * (allv.min(0) + allv.max(0)), 0.5 * (allv.max(0) - allv.min(0)).max() * 1.05
    pts = sample_surface(truth, 1500, 0) if truth is not None else None
    for i, m in enumerate(names):
        ax = fig.add_subplot(1, len(names), i + 1, projection="3d")
        _draw_mesh(ax, meshes[m], COLORS.get(m, "#888888"), 0.85, max_faces)
        if pts is not None:
            ax.scatter(pts[:, 0], pts[:, 1], pts[:, 2], s=0.6, c=COLORS["ground_truth"], alpha=0.5, depthshade=False)
        ax.set(xlim=(c[0] - r, c[0] + r), ylim=(c[1] - r, c[1] + r), zlim=(c[2] - r, c[2] + r))
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=25, azim=-60)
        ax.set_title(LABELS.get(m, m) + (" vs truth (grey)" if pts is not None else ""), fontsize=9)
        ax.tick_params(labelsize=6)
    return _save(fig, path)


def make_plots(series: dict, meshes: dict[str, Mesh], out_dir: Path) -> dict[str, Path]:
    """Write every figure the data allows into ``out_dir``; returns ``{name: png path}``."""
    out_dir = Path(out_dir)
    truth = None
    if "ground_truth/mesh_O/vertices" in series:
        truth = Mesh(series["ground_truth/mesh_O/vertices"], series["ground_truth/mesh_O/faces"])
    made = {
        "meshes": plot_meshes(meshes, truth, out_dir / "meshes.png"),
        "trajectories": plot_trajectories(series, out_dir / "trajectories.png"),
        "dynamics_errors": plot_errors(series, out_dir / "dynamics_errors.png"),
        "contacts": plot_contacts(series, out_dir / "contacts.png"),
        "tracking_errors": plot_tracking(series, out_dir / "tracking_errors.png"),
    }
    ms = _methods(series, "pos_err_m")
    if ms:
        t = series["dynamics/t"]
        fr = {}
        for m in ms:
            dp, dr = series[f"dynamics/{m}/pos_err_m"], series[f"dynamics/{m}/rot_err_deg"]
            valid = np.isfinite(dp)
            bad = valid & ((dp > 0.10) | (dr > 45.0))
            span = max(float(t[valid][-1] - t[0]), 1e-9) if valid.any() else 1.0
            fr[m] = [float(t[np.argmax(bad)] - t[0]) / span if bad.any() else 1.0]
        made["divergence"] = divergence_curves(fr, out_dir / "divergence.png")
    return {k: v for k, v in made.items() if v is not None}
