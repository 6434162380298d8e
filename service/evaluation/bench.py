"""Dataset benchmark: the paper's Table I (chamfer per object and method) and its dynamics figures, over a
set of sessions processed by the whole pipeline.

``run_bench(sessions, out_dir, *, preset, process)``:
- ``sessions`` is a folder of session folders (each with ``session.json``), or a list of
  ``service.synth.SynthSpec`` (generated into ``<out_dir>/sessions/``), or None for :func:`default_specs`
  (every object kind of the synthetic lab, several seeds, heavy occlusion, interactions in rotation);
- ``process(session_dir) -> report`` runs the pipeline on one session and returns its ``report.json``
  dict (the caller supplies it, so ``service`` does not depend on the flows);
- writes ``results.csv`` (one row per session and method), ``table_chamfer.{md,csv}`` (mean chamfer in cm,
  object × method, and "all" = mean over sessions), ``table_iou.{md,csv}``, ``table_dynamics.{md,csv}``
  (means over sessions), ``bench.json`` and figures under ``plots/`` (per-session chamfer and IoU with the
  methods of a session joined, divergence curves, pose errors).
A session that fails is recorded with its error and left out of the means.
"""

from __future__ import annotations

import csv
import json
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

METHODS = ("vision_only", "physics_only", "fused")
DYN_METHODS = ("vision_only", "physics_only", "fused", "ground_truth_geometry")
DYN_KEYS = ("pos_err_m", "rot_err_deg", "time_before_divergence_s", "time_before_divergence_frac", "contact_iou")


@dataclass
class BenchResult:
    out_dir: Path
    rows: list[dict]  # one per (session, method)
    failures: list[dict]
    tables: dict[str, Path] = field(default_factory=dict)
    plots: dict[str, Path] = field(default_factory=dict)


BENCH_INTERACTIONS: tuple[str, ...] = ("push", "pivot", "topple")


def default_specs(preset: str = "small", seeds: Sequence[int] = (0, 1, 2), occlusion: str = "heavy") -> list:
    """Every object kind × ``seeds``, heavy occlusion, interactions push/pivot/topple in rotation (the paper's
    interactions; the lab's impulsive ``strike`` is for the residual loop's sessions and is not in this set, so a
    seed's dataset stays the same sessions)."""
    from service.synth import OBJECT_KINDS, SynthSpec

    specs = []
    for k, kind in enumerate(OBJECT_KINDS):
        for seed in seeds:
            inter = BENCH_INTERACTIONS[(k + seed) % len(BENCH_INTERACTIONS)]
            specs.append(SynthSpec(object=kind, interaction=inter, seed=int(seed), preset=preset, occlusion=occlusion))
    return specs


def _object_kind(session_dir: Path) -> str:
    side = session_dir.parent / f"{session_dir.name}.effects.json"
    if side.is_file():
        try:
            return json.loads(side.read_text())["object"]["kind"]
        except (KeyError, ValueError):
            pass
    try:
        name = json.loads((session_dir / "session.json").read_text()).get("name") or session_dir.name
    except (OSError, ValueError):
        name = session_dir.name
    parts = name.split("_")
    # <kind>_<interaction>_<seed>: drop the last two parts when they look like that
    if len(parts) >= 3 and parts[-1].isdigit():
        return "_".join(parts[:-2])
    return name


def _sessions(sessions, out_dir: Path, preset: str, progress) -> list[Path]:
    if sessions is None:
        sessions = default_specs(preset)
    if isinstance(sessions, (str, Path)):
        root = Path(sessions)
        if not root.is_dir():
            raise FileNotFoundError(f"{root}: not a folder of sessions")
        found = sorted(p for p in root.iterdir() if (p / "session.json").is_file())
        if not found:
            raise FileNotFoundError(f"{root}: no session folder (with session.json) inside")
        return found
    from service.synth import make_session

    dirs = []
    for i, spec in enumerate(sessions):
        d = out_dir / "sessions" / spec.session_name()
        if not (d / "session.json").is_file():
            if progress:
                progress(0.3 * i / len(sessions), f"generating {spec.session_name()}")
            make_session(spec, d)
        dirs.append(d)
    return dirs


def _write_csv(path: Path, header: list[str], rows: list[list]) -> Path:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)
    return path


def _fmt(v, digits=2) -> str:
    if isinstance(v, (int, np.integer)) and not isinstance(v, bool):
        return str(v)
    return "—" if v is None or (isinstance(v, float) and not np.isfinite(v)) else f"{v:.{digits}f}"


def _write_md(path: Path, title: str, header: list[str], rows: list[list], best=None,
              reference_rows: tuple[str, ...] = ()) -> Path:
    """Markdown table; ``best`` = "min"/"max" (every column) or a list of those / None per column: the best
    method of a column is bold (rows named in ``reference_rows`` take no part)."""
    cols = list(zip(*[r[1:] for r in rows])) if rows else []
    per_col = best if isinstance(best, (list, tuple)) else [best] * len(cols)
    bold = set()
    ranked = [i for i, r in enumerate(rows) if r[0] not in reference_rows]
    for j, col in enumerate(cols):
        vals = [col[i] for i in ranked if col[i] is not None and np.isfinite(col[i])]
        if vals and per_col[j]:
            target = min(vals) if per_col[j] == "min" else max(vals)
            bold |= {(i, j) for i in ranked if col[i] == target}
    lines = [f"### {title}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for i, r in enumerate(rows):
        cells = [f"**{_fmt(v)}**" if (i, j) in bold else _fmt(v) for j, v in enumerate(r[1:])]
        lines.append("| " + " | ".join([str(r[0])] + cells) + " |")
    path.write_text("\n".join(lines) + "\n")
    return path


def _mean(xs) -> float | None:
    xs = [x for x in xs if x is not None and np.isfinite(x)]
    return float(np.mean(xs)) if xs else None


def _tables(rows: list[dict], out_dir: Path) -> dict[str, Path]:
    kinds = sorted({r["object"] for r in rows})
    out: dict[str, Path] = {}
    for metric, scale, name, best in (("chamfer_m", 100.0, "chamfer", "min"), ("iou", 1.0, "iou", "max")):
        header = ["method"] + kinds + ["all"]
        table = []
        for m in METHODS:
            sel = [r for r in rows if r["method"] == m]
            if not sel:
                continue
            per = [_mean([r[metric] for r in sel if r["object"] == k]) for k in kinds]
            allv = _mean([r[metric] for r in sel])
            table.append([m] + [None if v is None else v * scale for v in per] + [None if allv is None else allv * scale])
        unit = " (cm)" if name == "chamfer" else ""
        out[f"{name}_csv"] = _write_csv(out_dir / f"table_{name}.csv", header, table)
        out[f"{name}_md"] = _write_md(out_dir / f"table_{name}.md", f"Average {name}{unit} per object", header, table, best)
    header = ["method", "pos err (cm)", "rot err (deg)", "time before divergence (s)", "normalised", "contact agreement",
              "sessions"]
    table = []
    for m in DYN_METHODS:
        sel = [r for r in rows if r["method"] == m]
        if not sel:
            continue
        vals = [_mean([r[k] for r in sel]) for k in DYN_KEYS]
        vals[0] = None if vals[0] is None else 100 * vals[0]
        table.append([m] + vals + [len(sel)])
    out["dynamics_csv"] = _write_csv(out_dir / "table_dynamics.csv", header, table)
    out["dynamics_md"] = _write_md(out_dir / "table_dynamics.md", "Open-loop dynamics (means over sessions; "
                                   "true geometry is the reference, not a competitor)", header, table,
                                   ["min", "min", "max", "max", "max", None], reference_rows=("ground_truth_geometry",))
    return out


def _plots(rows: list[dict], out_dir: Path) -> dict[str, Path]:
    from service.report.plots import COLORS, LABELS, _figure, _save, divergence_curves

    pdir = out_dir / "plots"
    made: dict[str, Path] = {}
    sessions = sorted({r["session"] for r in rows})
    by = {(r["session"], r["method"]): r for r in rows}
    for metric, scale, ylabel, name in (("chamfer_m", 100, "chamfer (cm) ↓", "chamfer"), ("iou", 1, "volumetric IoU ↑", "iou"),
                                        ("pos_err_m", 100, "mean position error (cm) ↓", "pos_err"),
                                        ("rot_err_deg", 1, "mean rotation error (deg) ↓", "rot_err")):
        methods = METHODS if metric in ("chamfer_m", "iou") else DYN_METHODS
        present = [m for m in methods if any(by.get((s, m), {}).get(metric) is not None for s in sessions)]
        if not present:
            continue
        fig = _figure(1.6 + 1.6 * len(present), 4, left=0.8 / (1.6 + 1.6 * len(present)), bottom=0.1)
        ax = fig.add_subplot(1, 1, 1)
        for s in sessions:
            ys = [by.get((s, m), {}).get(metric) for m in present]
            xs = [i for i, y in enumerate(ys) if y is not None]
            ax.plot(xs, [ys[i] * scale for i in xs], color="#bbbbbb", lw=0.8, zorder=1)
        for i, m in enumerate(present):
            ys = [by[(s, m)][metric] * scale for s in sessions if by.get((s, m), {}).get(metric) is not None]
            ax.scatter([i] * len(ys), ys, color=COLORS.get(m), zorder=2, s=18)
        ax.set_xticks(range(len(present)), [LABELS.get(m, m) for m in present])
        ax.set(ylabel=ylabel, title=f"{ylabel.split(' (')[0]} per session", xlim=(-0.5, len(present) - 0.5))
        made[name] = _save(fig, pdir / f"{name}.png")
    frac = {m: [r["time_before_divergence_frac"] for r in rows if r["method"] == m
                and r.get("time_before_divergence_frac") is not None] for m in DYN_METHODS}
    p = divergence_curves({m: v for m, v in frac.items() if v}, pdir / "divergence.png",
                          "rollouts within 0.10 m / 45° of the tracked poses")
    if p:
        made["divergence"] = p
    return made


def run_bench(sessions: Path | Sequence | None, out_dir: Path, *, preset: str = "small",
              process: Callable[[Path], dict], progress: Callable[[float, str], None] | None = None) -> BenchResult:
    """Process every session with ``process`` and write the tables and figures (see module docstring)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    dirs = _sessions(sessions, out_dir, preset, progress)
    rows: list[dict] = []
    failures: list[dict] = []
    for i, d in enumerate(dirs):
        if progress:
            progress(0.3 + 0.65 * i / len(dirs), f"processing {d.name}")
        kind = _object_kind(d)
        t0 = time.perf_counter()
        try:
            rep = process(d)
        except Exception as e:  # one failed session must not stop the benchmark
            failures.append({"session": d.name, "object": kind, "error": f"{type(e).__name__}: {e}",
                             "traceback": traceback.format_exc(limit=5)})
            continue
        wall = time.perf_counter() - t0
        (out_dir / "reports").mkdir(exist_ok=True)
        (out_dir / "reports" / f"{d.name}.json").write_text(json.dumps(rep, indent=1, default=str))
        geo = rep.get("geometry") or {}
        dyn = rep.get("dynamics") or {}
        for m in sorted(set(METHODS) | set(DYN_METHODS)):
            g = geo.get(m) or {}
            y = dyn.get(m) or {}
            if not g and not y:
                continue
            rows.append({"session": d.name, "object": kind, "method": m, "chamfer_m": g.get("chamfer_m"),
                         "iou": g.get("iou"), **{k: y.get(k) for k in DYN_KEYS}, "wall_s": wall})
    header = ["session", "object", "method", "chamfer_m", "iou", *DYN_KEYS, "wall_s"]
    _write_csv(out_dir / "results.csv", header, [[r.get(h) for h in header] for r in rows])
    res = BenchResult(out_dir, rows, failures)
    if rows:
        res.tables = _tables(rows, out_dir)
        res.plots = _plots(rows, out_dir)
    summary = {"sessions": [d.name for d in dirs], "failures": failures, "preset": preset,
               "tables": {k: str(v) for k, v in res.tables.items()}, "plots": {k: str(v) for k, v in res.plots.items()}}
    (out_dir / "bench.json").write_text(json.dumps(summary, indent=1))
    if progress:
        progress(1.0, f"benchmark done: {len(dirs) - len(failures)}/{len(dirs)} sessions")
    return res
