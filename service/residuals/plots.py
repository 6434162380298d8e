"""Plots of the residual loop (PNG files written where the caller says; no global pyplot state).

- ``plot_rollout_by_mode``: held-out open-loop rollout error per contact mode, before/after the
  accepted effects (position mm, rotation deg).
- ``plot_heldout_errors``: per held-out block error before vs after, and every candidate's relative
  change of the held-out error on the frames where it acts (accepted ones highlighted).
- ``plot_step_residuals``: the contact stage's unexplained velocity change per mode (when given).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from service.residuals.types import MODES, ResidualOutputs


def _figure(w: float, h: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h), dpi=110)
    FigureCanvasAgg(fig)
    return fig


def _save(fig, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(str(path), format="png")
    return path


def plot_rollout_by_mode(out: ResidualOutputs, path: Path) -> Path:
    """Bar chart of held-out rollout errors by contact mode, before/after. Returns ``path``."""
    fig = _figure(9, 3.6)
    before, after = out.by_mode.get("rollout_before", {}), out.by_mode.get("rollout_after", {})
    modes = [m for m in MODES if before.get(m, {}).get("frames")]
    x = np.arange(len(modes))
    for k, (key, scale, unit) in enumerate((("pos_err_m", 1e3, "mm"), ("rot_err_deg", 1.0, "deg"))):
        ax = fig.add_subplot(1, 2, k + 1)
        b = [before[m][key] * scale for m in modes]
        a = [after[m][key] * scale for m in modes]
        ax.bar(x - 0.2, b, 0.4, label="before", color="#999999")
        ax.bar(x + 0.2, a, 0.4, label="after: " + (", ".join(out.accepted) or "nothing accepted"), color="#2b7bba")
        ax.set_xticks(x, [f"{m}\n({before[m]['frames']})" for m in modes], fontsize=8)
        ax.set_ylabel(f"mean {key.split('_')[0]} error ({unit})")
        ax.set_title(f"held-out rollout {key.split('_')[0]} error by mode")
        if k == 0:
            ax.legend(fontsize=8)
    return _save(fig, path)


def plot_heldout_errors(out: ResidualOutputs, path: Path) -> Path:
    """Per-block held-out error before vs after, and each candidate's held-out change."""
    fig = _figure(10, 4)
    ax = fig.add_subplot(1, 2, 1)
    b = np.asarray(out.series.get("heldout_error_before", []), float) * 1e3
    a = np.asarray(out.series.get("heldout_error_after", []), float) * 1e3
    if len(b):
        ax.scatter(b, a, s=8, alpha=0.6)
        lim = [max(min(b.min(), a.min()) * 0.8, 1e-3), max(b.max(), a.max()) * 1.2]
        ax.plot(lim, lim, "k--", lw=0.8)
        ax.set_xscale("log")
        ax.set_yscale("log")
    ax.set_xlabel("block error before (mm)")
    ax.set_ylabel("block error after (mm)")
    ax.set_title(f"{len(b)} held-out blocks, before vs after")
    ax = fig.add_subplot(1, 2, 2)
    cands = [c for c in out.candidates if np.isfinite(c.heldout_error_before) and c.heldout_error_before > 0]
    rel = [100 * (c.heldout_error_before - c.heldout_error_after) / c.heldout_error_before for c in cands]
    y = np.arange(len(cands))
    ax.barh(y, rel, color=["#2b7bba" if c.accepted else "#bbbbbb" for c in cands])
    ax.set_yticks(y, [f"{c.effect} (r{c.round + 1})" for c in cands], fontsize=8)
    ax.axvline(0, color="k", lw=0.8)
    ax.set_xlabel("held-out error fall on its frames (%)")
    ax.set_title("candidates (blue = accepted)")
    return _save(fig, path)


def plot_step_residuals(out: ResidualOutputs, path: Path) -> Path:
    """Mean |unexplained Δv| (linear m/s, angular rad/s) of the contact stage by mode."""
    fig = _figure(6, 3.4)
    ax = fig.add_subplot(1, 1, 1)
    st = out.by_mode.get("residual", {})
    modes = [m for m in MODES if st.get(m, {}).get("steps")]
    if not modes:
        ax.text(0.5, 0.5, "no per-step residuals from the contact stage", ha="center", va="center")
        ax.set_axis_off()
        return _save(fig, path)
    x = np.arange(len(modes))
    ax.bar(x - 0.2, [st[m].get("res_lin_norm", 0.0) for m in modes], 0.4, label="linear (m/s)")
    ax.bar(x + 0.2, [st[m].get("res_ang_norm", 0.0) for m in modes], 0.4, label="angular (rad/s)")
    ax.set_xticks(x, [f"{m}\n({st[m]['steps']})" for m in modes], fontsize=8)
    ax.set_ylabel("mean |residual|")
    ax.set_title("unexplained velocity change per step, by mode")
    ax.legend(fontsize=8)
    return _save(fig, path)
