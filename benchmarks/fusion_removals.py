"""Fusion with and without the removal of unsupported matter, on the stored outputs of a bench store.

For every session of a flow data folder (e.g. the ``--data-dir`` of ``vysics bench``), fusion is rerun on the stored
tracking and contact outputs three times: removals off, free-space carving only (the default), carving + thin parts
without evidence (``thin_open_radius`` 5 mm). Prints per session and on average the fused chamfer and IoU
(``service.evaluation`` geometry, ``EvaluationConfig()``), the fused and convex-hull volumes against the true volume,
and the voxels removed; with ``--dynamics`` also the fused model's open-loop rollout figures for "off" and "carve".

    python benchmarks/fusion_removals.py /tmp/bench11-data [--dynamics] [session names ...]

``--trunc-back MM [MM ...]``: instead, the default configuration against the same with a shallower band behind the
observed surface in the fit (``FusionConfig.sdf.trunc_back``, millimetres; ``none`` = τ, the symmetric band);
``--dynamics`` then rolls out every variant.

    python benchmarks/fusion_removals.py /tmp/geo/bench11_after_data --trunc-back 3 5

``--variants NAME=JSON ...``: instead, the default configuration against the same with each set of ``FusionConfig``
overrides (nested ``sdf`` fields allowed), e.g.

    python benchmarks/fusion_removals.py /tmp/me/bench11_final_data --variants 'no flying filter={"drop_flying": false}'
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", type=Path)
    ap.add_argument("names", nargs="*", help="only these sessions (names as in the ingest metrics)")
    ap.add_argument("--dynamics", action="store_true")
    ap.add_argument("--trunc-back", nargs="+", default=None, metavar="MM",
                    help="compare FusionConfig() with sdf.trunc_back set to these values (mm, or 'none')")
    ap.add_argument("--variants", nargs="+", default=None, metavar="NAME=JSON",
                    help="compare FusionConfig() with these overrides (JSON object; 'sdf' may hold SdfConfig fields)")
    a = ap.parse_args()
    if not (a.data / "artifacts" / "fusion").is_dir():
        ap.error(f"{a.data}: not a flow data folder with stored stage outputs (no artifacts/fusion/ in it)")

    import service.evaluation as evaluation
    from service.bundle import assemble_model
    from service.contact.types import ContactOutputs
    from service.evaluation.ground_truth import load_ground_truth
    from service.evaluation.run import geometry_metrics, tracking_metrics
    from service.evaluation.types import EvaluationConfig, EvaluationInputs
    from service.fusion import run
    from service.fusion.types import FusionConfig, FusionInputs
    from service.io import load_value
    from service.session.ingest import load_session
    from service.tracking.types import TrackingOutputs

    def manifests(stage: str) -> list[dict]:
        return [json.loads(m.read_text()) for m in (a.data / "artifacts" / stage).glob("*/manifest.json")]

    ingest = {m["key"]: m["metrics"] for m in manifests("ingest")}
    base = FusionConfig()
    variants = {"off": dataclasses.replace(base, carve_free_space=False, thin_open_radius=0.0),
                "carve": dataclasses.replace(base, carve_free_space=True, thin_open_radius=0.0),
                "carve+thin": dataclasses.replace(base, carve_free_space=True, thin_open_radius=0.005)}
    if a.trunc_back:
        variants = {"default": base}
        for v in a.trunc_back:
            tb = None if v.lower() == "none" else float(v) * 1e-3
            variants[f"trunc_back {v}"] = dataclasses.replace(base, sdf=dataclasses.replace(base.sdf, trunc_back=tb))
    if a.variants:
        variants = {"default": base}
        for v in a.variants:
            name, sep, text = v.partition("=")
            try:
                over = json.loads(text) if sep else None
            except json.JSONDecodeError as e:
                ap.error(f"--variants {v!r}: not JSON ({e})")
            if not isinstance(over, dict):
                ap.error(f"--variants {v!r}: expected NAME=JSON object of FusionConfig fields")
            sdf = over.pop("sdf", {})
            try:
                variants[name] = dataclasses.replace(base, sdf=dataclasses.replace(base.sdf, **sdf), **over)
            except (TypeError, ValueError) as e:
                ap.error(f"--variants {v!r}: not a valid FusionConfig ({e})")
    ecfg = EvaluationConfig()
    rows = []
    for m in sorted(manifests("contact"), key=lambda m: ingest[m["inputs"]["session"]]["name"]):
        meta = ingest[m["inputs"]["session"]]
        if a.names and meta["name"] not in a.names:
            continue
        sdir = a.data / "sessions" / meta["sha256"]
        session = load_session(sdir, meta["sha256"])
        tr = load_value(TrackingOutputs, a.data / "artifacts" / "tracking" / m["inputs"]["tracking"] / "value")
        co = load_value(ContactOutputs, a.data / "artifacts" / "contact" / m["key"] / "value")
        gt = load_ground_truth(sdir)  # evaluation only
        _, _, X_OG0 = tracking_metrics(EvaluationInputs(session=session, t=tr.t, X_WO=tr.X_WO, tracked=tr.tracked,
                                                        meshes={}, models={}), gt)
        res, line = {}, [meta["name"]]
        for name, cfg in variants.items():
            c0 = time.process_time()
            fu = run(FusionInputs(session, tr.X_WO, tr.tracked, tr.sdf, co.physible_points_O, co.physible_normals_O,
                                  co.physible_mesh), cfg)
            cpu = time.process_time() - c0
            geo = geometry_metrics({"fused": fu.mesh}, gt, X_OG0, ecfg)[0]["fused"]
            tm = fu.mesh.to_trimesh()
            r = {"chamfer_cm": 100 * geo["chamfer_m"], "iou": geo["iou"], "vol": tm.volume * 1e3,
                 "hull": tm.convex_hull.volume * 1e3, "true": geo["volume_true_m3"] * 1e3}
            txt = (f"{name}: chamfer {r['chamfer_cm']:.2f} cm, IoU {r['iou']:.2f}, volume {r['vol']:.3f} L, hull "
                   f"{r['hull']:.3f} L (true {r['true']:.3f} L), carved {fu.metrics['carved_voxels']:.0f}, thin "
                   f"{fu.metrics['thin_unsupported_voxels']:.0f} voxels [{cpu:.0f} s CPU]")
            if a.dynamics and (a.trunc_back or a.variants or name in ("off", "carve")):
                ev = evaluation.run(EvaluationInputs(session=session, t=tr.t, X_WO=tr.X_WO, tracked=tr.tracked,
                                                     meshes={"fused": fu.mesh},
                                                     models={"fused": assemble_model(session, co, fu.mesh)}), ecfg)
                d = ev.dynamics.get("fused") or {}
                r["pos_cm"], r["div_s"] = 100 * float(d.get("pos_err_m") or np.nan), d.get("time_before_divergence_s")
                txt += f", rollout {r['pos_cm']:.2f} cm, divergence {r['div_s']} s"
            res[name] = r
            line.append(txt)
        rows.append(res)
        print(" | ".join(line), flush=True)
    for name in variants:
        if not rows:
            break
        mean = {k: float(np.nanmean([r[name][k] for r in rows])) for k in ("chamfer_cm", "iou")}
        hull = float(np.mean([r[name]["hull"] / r[name]["true"] for r in rows]))
        print(f"mean {name}: chamfer {mean['chamfer_cm']:.3f} cm, IoU {mean['iou']:.3f}, hull / true volume {hull:.3f}")


if __name__ == "__main__":
    main()
