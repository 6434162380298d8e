"""``report.html``: the metrics of ``report.json`` for a person, with the figures.

One self-contained page (inline CSS, no scripts, no external assets). Figures are PNG files under
``<out_dir>/plots/`` referenced by relative links, or embedded as base64 with ``embed=True``.
A null metric is shown as "—" with its reason.
"""

from __future__ import annotations

import base64
import html
import json
import shutil
from pathlib import Path

SECTIONS = ("summary", "model", "tracking", "geometry", "dynamics", "residuals", "figures")
METHOD_LABELS = {"vision_only": "vision only", "physics_only": "physics only", "fused": "fused (Vysics)",
                 "ground_truth_geometry": "true geometry"}
FIGURE_TITLES = {
    "meshes": "Estimated geometry (colour) against the true shape (grey points), frame O",
    "trajectories": "Open-loop rollouts against the tracked trajectory",
    "dynamics_errors": "Rollout error over time (dashed: divergence thresholds 0.10 m / 45°)",
    "divergence": "Time before divergence",
    "contacts": "Robot–object contact: annotated and simulated",
    "tracking_errors": "Tracking error against ground truth",
    "mesh_overlay": "Visible mesh projected over frames at the tracked pose (green: tracked, red: lost; cyan: mask)",
    "velocities": "Tracked velocities (filtered backward differences)",
    "residuals_by_mode": "Rollout error by contact mode, before and after the accepted effects",
    "residuals_heldout": "Held-out error per block, before and after",
    "residuals_steps": "Per-step dynamics residuals of the fitted contact model",
}

CSS = """
body{font-family:-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:0;color:#222;background:#fafafa}
main{max-width:1100px;margin:0 auto;padding:24px}
h1{font-size:1.6em;margin-bottom:0}h2{border-bottom:2px solid #ddd;padding-bottom:4px;margin-top:2em}
.sub{color:#666;margin-top:4px}
table{border-collapse:collapse;margin:8px 0 16px 0;background:#fff}
th,td{border:1px solid #ddd;padding:5px 10px;text-align:right;font-variant-numeric:tabular-nums}
th{background:#f0f0f0}td.k,th.k{text-align:left}
.null{color:#999}.reason{color:#a55;font-size:.85em}
.ok{color:#1a7f37;font-weight:600}.no{color:#999}
figure{margin:16px 0;background:#fff;border:1px solid #e3e3e3;padding:8px}
figure img{max-width:100%}figcaption{color:#555;font-size:.9em;margin-top:4px}
nav a{margin-right:12px}pre{background:#fff;border:1px solid #ddd;padding:8px;overflow:auto;font-size:.8em}
"""


def _e(x) -> str:
    return html.escape(str(x))


def _fmt(v, scale: float = 1.0, digits: int = 3) -> str:
    if v is None:
        return '<span class="null">—</span>'
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, float)):
        return f"{v * scale:.{digits}g}" if abs(v * scale) < 1e-3 and v != 0 else f"{v * scale:.{digits}f}"
    return _e(v)


def _reasons(d: dict) -> str:
    rs = [f"{k[:-7] or 'all'}: {v}" if k != "reason" else str(v) for k, v in d.items()
          if (k == "reason" or k.endswith("_reason")) and v]
    return "".join(f'<div class="reason">{_e(r)}</div>' for r in rs)


def _kv_table(rows: list[tuple[str, str]]) -> str:
    body = "".join(f'<tr><td class="k">{_e(k)}</td><td>{v}</td></tr>' for k, v in rows)
    return f"<table>{body}</table>"


def _method_table(block: dict, cols: list[tuple[str, str, float, int]]) -> str:
    if not block:
        return '<p class="null">not computed</p>'
    head = '<tr><th class="k">method</th>' + "".join(f"<th>{_e(c[1])}</th>" for c in cols) + "<th class='k'>notes</th></tr>"
    rows = []
    for m, d in block.items():
        d = d or {}
        cells = "".join(f"<td>{_fmt(d.get(c[0]), c[2], c[3])}</td>" for c in cols)
        rows.append(f'<tr><td class="k">{_e(METHOD_LABELS.get(m, m))}</td>{cells}<td class="k">{_reasons(d)}</td></tr>')
    return f"<table>{head}{''.join(rows)}</table>"


def _section(sid: str, title: str, body: str) -> str:
    return f'<section id="{sid}"><h2>{_e(title)}</h2>{body}</section>'


def _summary(r: dict) -> str:
    s = r.get("session") or {}
    rows = [("session", _e(s.get("name", "?"))), ("frames", _fmt(s.get("frames"), digits=0)),
            ("sha256", f"<code>{_e(str(s.get('sha256', ''))[:16])}…</code>")]
    tim = r.get("timings_s") or {}
    t_rows = "".join(f'<tr><td class="k">{_e(k)}</td><td>{_fmt(v, digits=1)}</td></tr>' for k, v in tim.items())
    return _kv_table(rows) + (f"<h3>Timings (s)</h3><table>{t_rows}</table>" if t_rows else "")


def _model(r: dict) -> str:
    m = r.get("model") or {}
    if not m:
        return '<p class="null">no model</p>'
    fr = m.get("friction") or {}
    eff = m.get("effects") or {}
    inertia = m.get("inertia_O")
    rows = [
        ("mass (kg)", _fmt(m.get("mass_kg")) + ("" if m.get("mass_declared") else ' <span class="reason">default mass: not declared in the session</span>')),
        ("centre of mass in O (m)", _e(", ".join(f"{x:.4f}" for x in m.get("com_O") or []))),
        ("inertia about the CoM (kg m²)", "<br>".join(_e("  ".join(f"{x:.3e}" for x in row)) for row in (inertia or []))),
        ("friction object–table", _fmt(fr.get("object_table"))),
        ("friction object–robot", _fmt(fr.get("object_robot"))),
        ("effects", _e(", ".join(f"{k} = {v:.4g}" for k, v in eff.items())) if eff else "none"),
    ]
    return _kv_table(rows)


def _tracking(r: dict) -> str:
    t = r.get("tracking") or {}
    rows = [("frames tracked", _fmt(t.get("frames_tracked"), digits=0)), ("frames lost", _fmt(t.get("frames_lost"), digits=0))]
    masks = t.get("masks") or {}
    if masks.get("strip_fraction") is not None:
        rows.append(("mask pixels inside the mask's rim that look like background (median)",
                     f"{100 * masks['strip_fraction']:.1f} %"
                     + (": masks trimmed by colour for the geometry" if masks.get("trimmed_by_colour") else "")))
    vs = t.get("vs_ground_truth")
    body = _kv_table(rows)
    if vs is None:
        return body + '<p class="null">no ground truth</p>'
    keys = [("rot_err_deg_median", "rotation error, median (deg)", 1, 3), ("rot_err_deg_max", "rotation error, max (deg)", 1, 3),
            ("trans_err_m_median", "translation error, median (mm)", 1000, 2), ("trans_err_m_max", "translation error, max (mm)", 1000, 2)]
    body += _kv_table([(lab, _fmt(vs.get(k), s, d)) for k, lab, s, d in keys if k in vs]) + _reasons(vs)
    return body


def _residuals(r: dict) -> str:
    res = r.get("residuals")
    if not res:
        return '<p class="null">not run</p>'
    cands = res.get("candidates") or []
    head = ("<tr><th class='k'>effect</th><th class='k'>parameters</th><th>held-out error before</th><th>after</th>"
            "<th class='k'>acts on</th><th>where it acts: before</th><th>after</th><th>accepted</th></tr>")

    def acts(c: dict) -> str:
        a = c.get("acts_on") or {}
        return f"{a.get('component', '')} ({', '.join(a.get('modes') or [])})" if a else ""

    rows = "".join(
        f"<tr><td class='k'>{_e(c.get('effect'))}</td><td class='k'>{_e(', '.join(f'{k}={v:.4g}' for k, v in (c.get('params') or {}).items()))}</td>"
        f"<td>{_fmt(c.get('heldout_error_before'))}</td><td>{_fmt(c.get('heldout_error_after'))}</td>"
        f"<td class='k'>{_e(acts(c))}</td><td>{_fmt(c.get('heldout_acting_before'))}</td><td>{_fmt(c.get('heldout_acting_after'))}</td>"
        f"<td>{'<span class=ok>yes</span>' if c.get('accepted') else '<span class=no>no</span>'}</td></tr>"
        for c in cands)
    eb, ea = res.get("error_before") or {}, res.get("error_after") or {}
    summary = _kv_table([
        ("accepted", _e(", ".join(res.get("accepted") or []) or "none")),
        ("position error before → after (m)", f"{_fmt(eb.get('pos_err_m'))} → {_fmt(ea.get('pos_err_m'))}"),
        ("rotation error before → after (deg)", f"{_fmt(eb.get('rot_err_deg'))} → {_fmt(ea.get('rot_err_deg'))}"),
    ])
    return summary + (f"<table>{head}{rows}</table>" if cands else '<p class="null">no candidate effects</p>')


def _figures(plots: dict[str, Path], out_dir: Path, embed: bool) -> str:
    if not plots:
        return '<p class="null">no figures</p>'
    parts = []
    pdir = out_dir / "plots"
    for name, p in plots.items():
        p = Path(p)
        if embed:
            src = "data:image/png;base64," + base64.b64encode(p.read_bytes()).decode()
        else:
            pdir.mkdir(parents=True, exist_ok=True)
            dst = pdir / p.name
            if p.resolve() != dst.resolve():
                shutil.copyfile(p, dst)
            src = f"plots/{_e(p.name)}"
        cap = FIGURE_TITLES.get(name, name)
        parts.append(f'<figure id="fig-{_e(name)}"><img src="{src}" alt="{_e(cap)}"><figcaption>{_e(cap)}</figcaption></figure>')
    return "".join(parts)


def render_html(report: dict, figures_html: str) -> str:
    name = (report.get("session") or {}).get("name", "session")
    geo_cols = [("chamfer_m", "chamfer (cm)", 100, 3), ("iou", "volumetric IoU", 1, 3)]
    dyn_cols = [("pos_err_m", "mean position error (cm)", 100, 2), ("rot_err_deg", "mean rotation error (deg)", 1, 2),
                ("time_before_divergence_s", "time before divergence (s)", 1, 2),
                ("contact_iou", "contact agreement", 1, 3), ("contact_iou_jaccard", "contact IoU |A∩B|/|A∪B|", 1, 3)]
    geo = report.get("geometry")
    body = [
        f"<h1>Object model report: {_e(name)}</h1>",
        f'<p class="sub">format {_e(report.get("format", ""))}</p>',
        "<nav>" + "".join(f'<a href="#{s}">{s}</a>' for s in SECTIONS) + "</nav>",
        _section("summary", "Summary", _summary(report)),
        _section("model", "Model", _model(report)),
        _section("tracking", "Tracking", _tracking(report)),
        _section("geometry", "Geometry (after evaluation-only alignment)",
                 _method_table(geo, geo_cols) if geo else '<p class="null">no ground truth in the session</p>'),
        _section("dynamics", "Dynamics: open-loop rollouts against the tracked trajectory",
                 _method_table(report.get("dynamics") or {}, dyn_cols)),
        _section("residuals", "Residual analysis", _residuals(report)),
        _section("figures", "Figures", figures_html),
        "<details><summary>report.json</summary><pre>" + _e(json.dumps(report, indent=1, default=str)) + "</pre></details>",
    ]
    return ("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            f"<title>Vysics report: {_e(name)}</title><style>{CSS}</style></head><body><main>"
            + "".join(body) + "</main></body></html>")


def write_html(report: dict, plots: dict[str, Path], out_dir: Path, *, embed: bool = False) -> Path:
    """Write ``<out_dir>/report.html`` (figures copied under ``<out_dir>/plots/`` unless embedded)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "report.html"
    path.write_text(render_html(report, _figures(plots, out_dir, embed)), encoding="utf-8")
    return path
