import re

import numpy as np
import trimesh

from service.mesh import Mesh
from service.report.html import SECTIONS, write_html
from service.report.plots import make_plots


def fake_series(n=40):
    t = np.linspace(0, 1.3, n)
    tracked = np.c_[0.1 * t, 0 * t, 0.05 + 0 * t]
    s = {"dynamics/t": t, "dynamics/tracked_p_WO": tracked, "dynamics/annotated_contact": (t > 0.3) & (t < 0.9),
         "tracking/trans_err_m": 0.002 * np.ones(n), "tracking/rot_err_deg": 0.5 * np.ones(n)}
    for k, m in enumerate(("vision_only", "physics_only", "fused", "ground_truth_geometry")):
        p = tracked + [0.02 * k * t[-1], 0.0, 0.0] * t[:, None]
        s[f"dynamics/{m}/p_WO"] = p
        s[f"dynamics/{m}/pos_err_m"] = np.linalg.norm(p - tracked, axis=1)
        s[f"dynamics/{m}/rot_err_deg"] = 10.0 * k * t
        s[f"dynamics/{m}/contact"] = (t > 0.3 + 0.05 * k) & (t < 0.9)
    box = trimesh.creation.box((0.08, 0.06, 0.1))
    s["ground_truth/mesh_O/vertices"] = np.asarray(box.vertices)
    s["ground_truth/mesh_O/faces"] = np.asarray(box.faces)
    return s


REPORT = {
    "format": "vysics-report/1",
    "session": {"name": "box <push> & co", "sha256": "ab" * 32, "frames": 40},
    "timings_s": {"ingest": 1.0, "tracking": 2.0, "total": 3.0},
    "model": {"mass_kg": 0.3, "mass_declared": False, "com_O": [0, 0, 0.01], "inertia_O": np.eye(3).tolist(),
              "friction": {"object_table": 0.26, "object_robot": 0.15}, "effects": {"restitution": 0.4}},
    "tracking": {"frames_tracked": 40, "frames_lost": 0, "masks": {"trimmed_by_colour": True, "strip_fraction": 0.075},
                 "vs_ground_truth": {"rot_err_deg_median": 0.5, "trans_err_m_median": 0.002}},
    "geometry": {"vision_only": {"chamfer_m": 0.02, "iou": 0.5}, "physics_only": {"chamfer_m": None, "iou": None,
                                                                                    "reason": "the physics_only mesh is empty"},
                 "fused": {"chamfer_m": 0.01, "iou": 0.8}},
    "dynamics": {"fused": {"pos_err_m": 0.01, "rot_err_deg": 3.0, "time_before_divergence_s": 1.3, "contact_iou": None,
                           "contact_iou_reason": "no ground_truth/contacts.csv in the session"}},
    "residuals": {"candidates": [{"effect": "restitution", "params": {"e": 0.4}, "heldout_error_before": 0.02,
                                  "heldout_error_after": 0.01, "accepted": True}],
                  "accepted": ["restitution"], "error_before": {"pos_err_m": 0.02, "rot_err_deg": 5.0},
                  "error_after": {"pos_err_m": 0.01, "rot_err_deg": 3.0}},
}


def meshes():
    return {"vision_only": Mesh.from_trimesh(trimesh.creation.box((0.04, 0.06, 0.1))),
            "physics_only": Mesh.from_trimesh(trimesh.creation.box((0.09, 0.07, 0.1))),
            "fused": Mesh.from_trimesh(trimesh.creation.icosphere(2, 0.05))}


def test_plots_and_html_with_every_section(tmp_path):
    plots = make_plots(fake_series(), meshes(), tmp_path / "work")
    assert set(plots) == {"meshes", "trajectories", "dynamics_errors", "contacts", "tracking_errors", "divergence"}
    for p in plots.values():
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    out = tmp_path / "bundle"
    page = write_html(REPORT, plots, out)
    text = page.read_text()
    for s in SECTIONS:
        assert f'<section id="{s}">' in text
    srcs = re.findall(r'<img src="([^"]+)"', text)
    assert len(srcs) == len(plots)
    for src in srcs:
        assert src.startswith("plots/") and (out / src).is_file()
    # values and reasons are shown, text is escaped
    assert "box &lt;push&gt; &amp; co" in text and "<push>" not in text
    assert "the physics_only mesh is empty" in text and "no ground_truth/contacts.csv" in text
    assert "1.000" in text  # fused chamfer 0.01 m shown as 1.000 cm
    assert "default mass" in text and "restitution" in text
    assert "7.5 %: masks trimmed by colour" in text


def test_embedded_figures_need_no_files(tmp_path):
    plots = make_plots(fake_series(), {}, tmp_path / "work")
    assert "meshes" not in plots
    page = write_html({"format": "vysics-report/1"}, plots, tmp_path / "b", embed=True)
    text = page.read_text()
    assert text.count('src="data:image/png;base64,') == len(plots)
    assert not (tmp_path / "b" / "plots").exists()
    for s in SECTIONS:
        assert f'<section id="{s}">' in text
