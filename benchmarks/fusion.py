"""Fusion speed and accuracy on a synthetic 10 s, 640x480 session of a box seen from one side.

The camera sees only the +x and +z faces of an 8 x 6 x 4 cm box; 70 contact points with their normals
lie on the hidden bottom, back and side faces. Prints the wall time of ``service.fusion.run`` with the
default ``FusionConfig`` (wall and CPU time: on a shared machine the CPU time is the better
estimate of the wall time on an idle one) and the chamfer distance (two-way mean, m) of the vision-only and fused
meshes to the true box, plus, with --compare, the sampling-extent and initialisation variants.

    python benchmarks/fusion.py [--frames 300] [--compare]

With ``--data DIR --sha SHA`` it instead reruns fusion variants on a session already processed by the
flow (``DIR`` = the flow's data folder holding ``sessions/`` and ``artifacts/``; the newest stored tracking
and contact outputs are used) and scores each fused mesh with ``service.evaluation`` against the
session's ground truth, as the report does:

    python benchmarks/pipeline.py --work W --preset fast     # process a synthetic session
    python benchmarks/fusion.py --data W/data --sha <session sha256>

With ``--data DIR --rerun-all`` it reruns fusion with the default ``FusionConfig`` on every session of a
store (e.g. the ``--data-dir`` of ``vysics bench``), each with the tracking and contact outputs stored for
it, evaluates geometry and dynamics with ``EvaluationConfig()`` as the pipeline does, and prints the
chamfer table (cm) per session and the means; with ``--reports DIR`` (the bench's ``reports/``) it also
prints the fused chamfer the stored run had (fusion before / after on identical inputs):

    vysics bench --out B --preset small --seeds 21 --data-dir D
    python benchmarks/fusion.py --data D --rerun-all --reports B/reports
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from service.fusion import FusionConfig, FusionInputs, SampleExtents, run, session_rays  # noqa: E402
from service.sdf import SdfConfig, extract_mesh, fit_sdf, sdf_query  # noqa: E402
from tests.fusion.scenes import box_mesh, chamfer, face_points, hidden_contacts, write_box_session  # noqa: E402


def face_errors(grid) -> str:
    out = []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            pts, _ = face_points(300, axis, sign, np.random.default_rng(1), margin=0.2)
            out.append(f"{'xyz'[axis]}{'+' if sign > 0 else '-'} {1000 * np.mean(sdf_query(grid, pts)):+.1f}")
    return ", ".join(out)


def stored_session(data: Path, sha: str) -> None:
    """Fusion variants on a processed session, scored against its ground truth by service.evaluation."""
    from service.contact.types import ContactOutputs
    from service.evaluation.ground_truth import load_ground_truth
    from service.evaluation.run import geometry_metrics, tracking_metrics
    from service.evaluation.types import EvaluationConfig, EvaluationInputs
    from service.io import load_value
    from service.session.ingest import load_session
    from service.tracking.types import TrackingOutputs

    root = data / "sessions" / sha
    session = load_session(root, sha)

    def newest(stage: str) -> Path:
        return max((data / "artifacts" / stage).glob("*/value"), key=lambda p: p.stat().st_mtime)

    tr = load_value(TrackingOutputs, newest("tracking"))
    co = load_value(ContactOutputs, newest("contact"))
    gt = load_ground_truth(root)
    _, _, X_OG = tracking_metrics(EvaluationInputs(session, tr.t, tr.X_WO, tr.tracked, {}, {}), gt)
    ecfg = EvaluationConfig.fast()

    def score(name: str, mesh, extra: str = "") -> None:
        g = geometry_metrics({name: mesh}, gt, X_OG, ecfg)[0][name]
        print(f"{name}: chamfer {1000 * g['chamfer_m']:.1f} mm, IoU {g['iou']:.3f}, volume {1e6 * g['volume_m3']:.0f} cm3 "
              f"(true {1e6 * g['volume_true_m3']:.0f}){extra}", flush=True)

    print(f"session {session.name}: {session.n_frames} frames, {len(co.physible_points_O)} physible points")
    score("vision_only", tr.visible_mesh)
    score("physics_only", co.physible_mesh)
    inputs = FusionInputs(session, tr.X_WO, tr.tracked, tr.sdf, co.physible_points_O, co.physible_normals_O,
                          co.physible_mesh)
    base = FusionConfig()
    paper = dataclasses.replace(base, table_points="points", drop_penetrating=False)
    for name, cfg in [
        ("fused, default", base),
        ("fused, every physible point as a point, none dropped (paper)", paper),
        ("fused, table contacts as points", dataclasses.replace(base, table_points="points")),
        ("fused, penetrating points kept", dataclasses.replace(base, drop_penetrating=False)),
        ("fused, no free-space drop", dataclasses.replace(base, free_space_drop=False)),
        ("fused, final-code extents", dataclasses.replace(base, extents=SampleExtents.final_code())),
        ("fused, visible start", dataclasses.replace(base, init="visible")),
    ]:
        c0 = time.process_time()
        out = run(inputs, cfg)
        score(name, out.mesh, f", {time.process_time() - c0:.1f} s CPU")


def rerun_all(data: Path, reports: Path | None) -> None:
    """Default fusion on every session of a store, on its stored tracking/contact outputs; full evaluation."""
    import json

    import service.evaluation as evaluation
    from service.bundle import assemble_model
    from service.contact.types import ContactOutputs
    from service.evaluation.types import EvaluationConfig, EvaluationInputs
    from service.io import load_value
    from service.session.ingest import load_session
    from service.tracking.types import TrackingOutputs

    def manifests(stage: str) -> list[dict]:
        return [json.loads(m.read_text()) for m in (data / "artifacts" / stage).glob("*/manifest.json")]

    ingest = {m["key"]: m["metrics"] for m in manifests("ingest")}
    rows = []
    for m in sorted(manifests("contact"), key=lambda m: ingest[m["inputs"]["session"]]["name"]):
        meta = ingest[m["inputs"]["session"]]
        session = load_session(data / "sessions" / meta["sha256"], meta["sha256"])
        tr = load_value(TrackingOutputs, data / "artifacts" / "tracking" / m["inputs"]["tracking"] / "value")
        co = load_value(ContactOutputs, data / "artifacts" / "contact" / m["key"] / "value")
        c0, t0 = time.process_time(), time.perf_counter()
        fu = run(FusionInputs(session, tr.X_WO, tr.tracked, tr.sdf, co.physible_points_O, co.physible_normals_O,
                              co.physible_mesh), FusionConfig())
        cpu, wall = time.process_time() - c0, time.perf_counter() - t0
        meshes = {"vision_only": tr.visible_mesh, "physics_only": co.physible_mesh, "fused": fu.mesh}
        models = {k: assemble_model(session, co, v) for k, v in meshes.items() if not v.is_empty}
        ev = evaluation.run(EvaluationInputs(session=session, t=tr.t, X_WO=tr.X_WO, tracked=tr.tracked,
                                             meshes=meshes, models=models), EvaluationConfig())
        cd = {k: 100 * ev.geometry[k]["chamfer_m"] for k in meshes}
        before = None
        if reports is not None and (reports / f"{meta['name']}.json").is_file():
            before = 100 * json.loads((reports / f"{meta['name']}.json").read_text())["geometry"]["fused"]["chamfer_m"]
        div = {k: (ev.dynamics.get(k) or {}).get("time_before_divergence_s") for k in ("fused", "ground_truth_geometry")}
        rows.append((meta["name"], cd, before, div))
        print(f"{meta['name']}: chamfer vision {cd['vision_only']:.2f}, physics {cd['physics_only']:.2f}, fused "
              f"{cd['fused']:.2f}" + ("" if before is None else f" (stored run {before:.2f})") + f" cm; fusion "
              f"{wall:.1f} s wall, {cpu:.1f} s CPU; dropped {fu.metrics['physible_penetrating_dropped']:.0f} "
              f"penetrating, {fu.metrics['physible_free_dropped']:.0f} seen-through", flush=True)
    if not rows:
        raise SystemExit(f"{data}: no stored contact outputs")
    mean = {k: float(np.mean([r[1][k] for r in rows])) for k in rows[0][1]}
    print(f"mean chamfer (cm): vision {mean['vision_only']:.2f}, physics {mean['physics_only']:.2f}, fused "
          f"{mean['fused']:.2f}; fused / vision {mean['fused'] / mean['vision_only']:.2f}")
    if all(r[2] is not None for r in rows):
        b = float(np.mean([r[2] for r in rows]))
        print(f"stored run: fused {b:.2f}, fused / vision {b / mean['vision_only']:.2f}")
    td = [r[3] for r in rows if None not in r[3].values()]
    if td:
        f, g = np.mean([d["fused"] for d in td]), np.mean([d["ground_truth_geometry"] for d in td])
        print(f"time before divergence: fused {f:.2f} s, true geometry {g:.2f} s, ratio {f / g:.2f}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", type=Path, help="flow data folder of a processed session (with --sha)")
    ap.add_argument("--sha", help="sha256 of the processed session")
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--compare", action="store_true", help="also run the extent and init variants")
    ap.add_argument("--rerun-all", action="store_true", help="with --data: default fusion on every stored session")
    ap.add_argument("--reports", type=Path, help="with --rerun-all: the bench's reports/ folder (stored fused chamfer)")
    args = ap.parse_args()
    if args.data is not None and args.rerun_all:
        rerun_all(args.data, args.reports)
        return
    if args.data is not None:
        stored_session(args.data, args.sha)
        return
    truth = box_mesh()
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        session, X_WO = write_box_session(tmp, n_frames=args.frames, width=args.width, height=args.height)
        print(f"session: {args.frames} frames {args.width}x{args.height} rendered in {time.perf_counter() - t0:.1f} s")
        tracked = np.ones(len(X_WO), bool)
        cfg = FusionConfig()
        t0 = time.perf_counter()
        visible = fit_sdf(session_rays(session, X_WO, tracked, cfg), SdfConfig())
        print(f"vision-only pass (SdfConfig()): {time.perf_counter() - t0:.1f} s")
        P, N = hidden_contacts(np.random.default_rng(0))
        inputs = FusionInputs(session, X_WO, tracked, visible, P, N, truth)
        print(f"vision-only: chamfer {1000 * chamfer(extract_mesh(visible), truth):.2f} mm; "
              f"mean S on true faces (mm): {face_errors(visible)}")
        variants = [("default (paper-text extents, hull init)", cfg)]
        if args.compare:
            variants += [
                ("final-code extents, hull init", dataclasses.replace(cfg, extents=SampleExtents.final_code())),
                ("paper-text extents, visible init", dataclasses.replace(cfg, init="visible")),
                ("final-code extents, visible init",
                 dataclasses.replace(cfg, init="visible", extents=SampleExtents.final_code())),
            ]
        for name, c in variants:
            t0, c0 = time.perf_counter(), time.process_time()
            out = run(inputs, c)
            dt, dc = time.perf_counter() - t0, time.process_time() - c0
            print(f"fused [{name}]: run {dt:.1f} s wall, {dc:.1f} s CPU (rays {out.metrics['time_rays_s']:.1f} s, "
                  f"fit {out.metrics['time_fit_s']:.1f} s); chamfer {1000 * chamfer(out.mesh, truth):.2f} mm; "
                  f"mean S on true faces (mm): {face_errors(out.sdf)}", flush=True)


if __name__ == "__main__":
    main()
