"""Contact-implicit learning on real toss data: geometry, inertia, rollouts, learning curve, speed.

Usage (prints figures and the command that reproduces them):
    python benchmarks/contact.py cube      [--sizes 2 4 8 16 32] [--steps 400] [--heldout 30]
    python benchmarks/contact.py tagslam   [--steps 400]
    python benchmarks/contact.py speed     [--epochs 300]
    python benchmarks/contact.py synth
    python benchmarks/contact.py pipeline-input [--preset tiny|small|full] [--config fast|default]

cube:    148 Hz ContactNets cube tosses, no vision term. The shared ids are split here (seed 0): ``heldout``
         tosses for open-loop rollouts, training sets of growing size drawn from the rest (nested).
         Learned half-extents vs 0.0524 m, principal inertia / (m s²/6) of the true uniform cube, rollout
         position/rotation error of the learned model next to the true cube (0.1048 m box, m = 0.37 kg,
         uniform inertia) simulated by the same code (service/contact/simulate.py).
tagslam: 30 Hz TagSLAM tosses of the prism and the napkin box: chamfer distance (two-way mean, 2000 surface
         samples each, cm) of the learned hull to the ground-truth mesh in the trajectories' body frame
         (no alignment; the meta says the gt frame agrees to 1-2 cm), and after centring both meshes.
speed:   a 10 s push session at 30 Hz (299 transitions) with the end-effector sphere contact.
pipeline-input: synthetic session -> ingest -> tracking -> contact (the inputs the pipeline builds), per-phase
         timings and the contact stage's own breakdown.
synth:   synthetic push sessions (service.synth physics only): support-function error on the contacted faces.

Loss weights: PLL's, except the penetration weight ``--w-pen`` (default 50 = ``ContactConfig.tosses()``).
Geometry ``--geometry``: cube/tagslam default to the learnable polytope (as ``ContactConfig.tosses()``), synth to
the deep support function (as ``ContactConfig()``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from service.contact.data import load_trajectories  # noqa: E402
from service.contact.fit import run  # noqa: E402
from service.contact.simulate import Body, box_vertices, rollout_trajectories  # noqa: E402
from service.contact.types import ContactConfig, ContactInputs  # noqa: E402
from service.session.types import Friction  # noqa: E402

from _overrides import stage_overrides  # noqa: E402

SHARED = Path(__file__).resolve().parents[2] / "shared"  # shared/ sits beside the repository
DATA = Path(SHARED, "data/real")
CUBE_HALF = 0.0524
CUBE_MASS = 0.37


def _inputs(trajs, dt, mass=CUBE_MASS, friction=Friction(), ee=None, table_height=0.0):
    return ContactInputs(dt=dt, states=tuple(trajs), ee_p_W=None if ee is None else ee[0],
                         ee_v_W=None if ee is None else ee[1], ee_radius=0.0195, table_height=table_height,
                         friction=friction, mass=mass, mass_declared=False, visible_points_O=None,
                         init_vertices_O=None)


def _epochs_for(n_transitions: int, batch: int, steps: int) -> int:
    per_epoch = max(1, -(-n_transitions // batch))
    return max(5, -(-steps // per_epoch))


def _chamfer(a, b, n=2000, seed=0):
    import trimesh
    from scipy.spatial import cKDTree

    pa = trimesh.sample.sample_surface(a, n, seed=seed)[0]
    pb = trimesh.sample.sample_surface(b, n, seed=seed + 1)[0]
    da = cKDTree(pb).query(pa)[0]
    db = cKDTree(pa).query(pb)[0]
    return 0.5 * (da.mean() + db.mean())


def bench_cube(args) -> dict:
    trajs, ids, dt, _ = load_trajectories(DATA / "contactnets_cube_toss" / "data.npz")
    rng = np.random.default_rng(0)
    perm = rng.permutation(len(trajs))
    held = perm[: args.heldout]
    pool = perm[args.heldout :]
    I_true = CUBE_MASS * (2 * CUBE_HALF) ** 2 / 6
    mu = args.mu
    true_body = Body(box_vertices([CUBE_HALF] * 3), CUBE_MASS, np.zeros(3), I_true * np.eye(3), mu)
    t0 = time.perf_counter()
    true_roll = rollout_trajectories(true_body, [trajs[k] for k in held], dt, table_height=args.table_height)
    t_roll = time.perf_counter() - t0
    print(f"true cube rollout on {len(held)} held-out tosses: pos {100 * true_roll['pos_err_m']:.2f} cm, "
          f"rot {true_roll['rot_err_deg']:.1f} deg (mu={mu}, {t_roll:.0f} s)")
    rows = []
    for n in args.sizes:
        sel = pool[:n]
        tr = [trajs[k] for k in sel]
        S = sum(len(X) - 1 for X in tr)
        cfg = ContactConfig(width=args.width, epochs=_epochs_for(S, args.batch, args.steps), batch_size=args.batch,
                            seed=0, learn_friction=args.learn_friction, w_pen=args.w_pen,
                            geometry=args.geometry or "polytope")
        t0 = time.perf_counter()
        out = run(_inputs(tr, dt, friction=Friction(mu, 0.15), table_height=args.table_height), cfg)
        wall = time.perf_counter() - t0
        V = np.asarray(out.physible_mesh.vertices)
        half = 0.5 * np.ptp(V, axis=0)
        ev = np.linalg.eigvalsh(out.inertia_O)
        body = Body(V, out.mass, out.com_O, out.inertia_O, out.friction.object_table)
        roll = rollout_trajectories(body, [trajs[k] for k in held], dt, n_contacts=8, table_height=args.table_height)
        # decomposition: which learned part costs the rollout accuracy (same held-out tosses, same simulator)
        tg_li = rollout_trajectories(Body(true_body.vertices_O, out.mass, out.com_O, out.inertia_O, mu),
                                     [trajs[k] for k in held], dt, n_contacts=8, table_height=args.table_height)
        lg_ti = rollout_trajectories(Body(V, CUBE_MASS, np.zeros(3), I_true * np.eye(3), mu),
                                     [trajs[k] for k in held], dt, n_contacts=8, table_height=args.table_height)
        corner = float((V @ (np.ones(3) / np.sqrt(3))).max())
        from scipy.spatial import ConvexHull

        vol_ratio = float(ConvexHull(V).volume / (2 * CUBE_HALF) ** 3)
        row = {
            "n_train": n, "transitions": S, "epochs": cfg.epochs, "wall_s": wall,
            "half_extents_m": half.tolist(), "half_err_pct": (100 * (half / CUBE_HALF - 1)).tolist(),
            "inertia_ratio": (ev / I_true).tolist(), "com_m": out.com_O.tolist(),
            "mu_table": out.friction.object_table,
            "rollout_pos_cm": 100 * roll["pos_err_m"], "rollout_rot_deg": roll["rot_err_deg"],
            "rollout_true_geometry_learned_inertia": (100 * tg_li["pos_err_m"], tg_li["rot_err_deg"]),
            "rollout_learned_geometry_true_inertia": (100 * lg_ti["pos_err_m"], lg_ti["rot_err_deg"]),
            "corner_support_m": corner, "volume_ratio": vol_ratio,
            "s_per_epoch": out.metrics["time_s_per_epoch"], "solver_s": out.metrics["time_solver_s"],
            "fwd_bwd_s": out.metrics["time_forward_backward_s"],
            "solver_transitions_per_s": out.metrics["time_transitions_solved_per_s"],
        }
        rows.append(row)
        print(f"n={n:3d} S={S:5d} ep={cfg.epochs:4d} half={np.round(1000 * half, 1)} mm "
              f"(err {np.round(row['half_err_pct'], 1)} %) I/I_true={np.round(row['inertia_ratio'], 2)} "
              f"rollout pos {row['rollout_pos_cm']:.2f} cm rot {row['rollout_rot_deg']:.1f} deg; "
              f"true geometry + learned inertia {tg_li['rot_err_deg']:.1f} deg, learned geometry + true inertia "
              f"{lg_ti['rot_err_deg']:.1f} deg; support along (1,1,1) {1000 * corner:.1f} mm (true "
              f"{1000 * CUBE_HALF * np.sqrt(3):.1f}), hull volume / cube {vol_ratio:.2f} | "
              f"{wall:.0f} s, {row['s_per_epoch']:.2f} s/epoch (solver {row['solver_s']:.0f} s, "
              f"fwd/bwd {row['fwd_bwd_s']:.0f} s, {row['solver_transitions_per_s']:.0f} transitions/s)")
        sys.stdout.flush()
    return {"true_cube_rollout": {k: v for k, v in true_roll.items() if k not in ("sim", "per_trajectory")},
            "heldout_ids": [int(ids[k]) for k in held], "rows": rows}


def bench_tagslam(args) -> dict:
    import trimesh

    res = {}
    for name in ("tagslam_toss_prism", "tagslam_toss_napkin"):
        trajs, ids, dt, meta = load_trajectories(DATA / name / "data.npz")
        S = sum(len(X) - 1 for X in trajs)
        cfg = ContactConfig(width=args.width, epochs=_epochs_for(S, args.batch, args.steps), batch_size=args.batch,
                            w_pen=args.w_pen, geometry=args.geometry or "polytope")
        mass = float(meta.get("values_in_source_urdf_bundlesdf_<obj>_mesh.urdf", {}).get("mass_kg", CUBE_MASS))
        t0 = time.perf_counter()
        out = run(_inputs(trajs, dt, mass=mass), cfg)
        wall = time.perf_counter() - t0
        gt = trimesh.load(str(DATA / name / "gt_mesh.obj"), force="mesh")
        learned = out.physible_mesh.to_trimesh()
        cd = _chamfer(learned, gt)
        lc = learned.copy()
        gc = gt.copy()
        lc.apply_translation(-lc.centroid)
        gc.apply_translation(-gc.centroid)
        cd_c = _chamfer(lc, gc)
        res[name] = {"chamfer_cm": 100 * cd, "chamfer_centred_cm": 100 * cd_c, "wall_s": wall,
                     "learned_extents_m": np.ptp(learned.vertices, axis=0).tolist(),
                     "gt_extents_m": np.ptp(gt.vertices, axis=0).tolist(), "transitions": S, "mass": mass}
        print(f"{name}: chamfer {100 * cd:.2f} cm (centred {100 * cd_c:.2f} cm), learned extents "
              f"{np.round(np.ptp(learned.vertices, axis=0), 3)} vs gt {np.round(np.ptp(gt.vertices, axis=0), 3)} "
              f"({S} transitions, {wall:.0f} s)")
    return res


def _push_session(kind: str, interaction: str, seed: int, n_frames: int = 300, fps: float = 30.0):
    """Physics-only synthetic session (service.synth.sim, pybullet): states of the mesh frame M (= O) and the
    sphere at the frame times; velocities by backward differences (as the tracking stage delivers them)."""
    from service.synth.objects import make_object
    from service.synth.sim import simulate as synth_simulate
    from service.synth.types import HiddenEffects
    from service.transforms import mat_to_quat, quat_make_continuous, so3_log

    rng = np.random.default_rng(seed)
    obj = make_object(kind)
    rec = synth_simulate(obj, interaction=interaction, table_h=0.0, start_xy=np.array([0.5, 0.0]),
                         start_yaw=float(rng.uniform(-np.pi, np.pi)), lateral=np.array([0.0, 1.0]), n_frames=n_frames,
                         fps=fps, physics_hz=240.0, mu_ot=0.26, mu_or=0.15, effects=HiddenEffects(), rng=rng)
    X = rec.X_WM
    dt = 1.0 / fps
    q = quat_make_continuous(mat_to_quat(X[:, :3, :3]))
    p = X[:, :3, 3]
    v = np.zeros_like(p)
    v[1:] = np.diff(p, axis=0) / dt
    w = np.zeros_like(p)
    w[1:] = so3_log(np.swapaxes(X[:-1, :3, :3], -1, -2) @ X[1:, :3, :3]) / dt
    v[0], w[0] = v[1], w[1]
    S = np.concatenate([q, p, w, v], -1)
    ee = rec.ee_frames
    ev = np.zeros_like(ee)
    ev[1:] = np.diff(ee, axis=0) / dt
    ev[0] = ev[1]
    return obj, S, ee, ev, dt


def bench_speed(args) -> dict:
    """A 10 s push session at 30 Hz (300 transitions) with the sphere contact: wall time of ``run``."""
    obj, S, ee, ev, dt = _push_session("baking_box", "push", 0)
    cfg = ContactConfig(epochs=args.epochs, w_pen=args.w_pen)
    t0 = time.perf_counter()
    out = run(_inputs([S], dt, mass=obj.mass, ee=((ee,), (ev,))), cfg)
    wall = time.perf_counter() - t0
    m = out.metrics
    print(f"{len(S) - 1} transitions, {cfg.epochs} epochs, width {cfg.width}: {wall:.1f} s total "
          f"({m['time_s_per_epoch']:.3f} s/epoch; solver {m['time_solver_s']:.1f} s, hull+closest point "
          f"{m['time_hull_s']:.1f} s, forward/backward {m['time_forward_backward_s']:.1f} s; "
          f"{m['time_transitions_solved_per_s']:.0f} transitions/s in the solver), torch threads {torch.get_num_threads()}")
    return {"wall_s": wall, **m}


def bench_synth(args) -> dict:
    """Geometry error on the contacted faces: for every physible (point, direction) pair, |h_learned(n) − h_true(n)|
    with h the support function (learned hull vs the true mesh, same frame)."""
    res = {}
    for kind, inter in [("baking_box", "push"), ("baking_box", "topple"), ("prism", "pivot")]:
        obj, S, ee, ev, dt = _push_session(kind, inter, 1)
        cfg = ContactConfig(epochs=args.epochs, w_pen=args.w_pen, geometry=args.geometry or "dsf",
                            **args.overrides)
        t0 = time.perf_counter()
        out = run(_inputs([S], dt, mass=obj.mass, ee=((ee,), (ev,))), cfg)
        wall = time.perf_counter() - t0
        N = out.physible_normals_O
        Vt = np.asarray(obj.mesh.vertices)
        Vl = np.asarray(out.physible_mesh.vertices)
        if len(N):
            h_true = (N @ Vt.T).max(-1)
            h_learn = (N @ Vl.T).max(-1)
            err = np.abs(h_learn - h_true)
            e_mean, e_med = float(err.mean()), float(np.median(err))
        else:
            e_mean = e_med = float("nan")
        com_true = np.asarray(obj.mesh.center_mass, float)  # uniform object (origin at its centroid), no CoM offset
        com_err = 1000 * float(np.linalg.norm(out.com_O - com_true))
        res[f"{kind}/{inter}"] = {"contacted_face_err_mean_mm": 1000 * e_mean, "median_mm": 1000 * e_med,
                                  "com_err_mm": com_err,
                                  "physible_pairs": int(len(N)), "wall_s": wall,
                                  "learned_extents_m": np.ptp(Vl, axis=0).tolist(),
                                  "true_extents_m": np.ptp(Vt, axis=0).tolist()}
        print(f"{kind}/{inter}: contacted-face support error mean {1000 * e_mean:.1f} mm (median {1000 * e_med:.1f} mm) "
              f"over {len(N)} physible pairs; extents learned {np.round(np.ptp(Vl, axis=0), 3)} true "
              f"{np.round(np.ptp(Vt, axis=0), 3)}; CoM error {com_err:.1f} mm ({wall:.0f} s)")
        sys.stdout.flush()
    return res


def bench_pipeline_input(args) -> dict:
    """The contact stage on the inputs the pipeline gives it: synthetic session -> ingest -> tracking -> contact,
    each phase timed. ``--preset tiny`` (160x120, 60 frames) or ``full`` (640x480, 300 frames = 10 s);
    ``--config fast|default`` for both tracking and contact (as the pipeline's presets)."""
    import dataclasses
    import tempfile

    from service.contact import inputs_from_tracking
    from service.session import ingest
    from service.synth import make_session
    from service.synth.objects import make_object
    from service.synth.types import SynthSpec
    from service.tracking import run as tracking_run
    from service.tracking.types import TrackingConfig, TrackingInputs

    tmp = Path(tempfile.mkdtemp(prefix="contact_bench_"))
    spec = SynthSpec(preset=args.preset, seed=args.seed)
    times = {}
    t = time.perf_counter()
    make_session(spec, tmp / "raw")
    times["synth_s"] = time.perf_counter() - t
    t = time.perf_counter()
    session = ingest(tmp / "raw", tmp / "ingested")
    times["ingest_s"] = time.perf_counter() - t
    t = time.perf_counter()
    tr = tracking_run(TrackingInputs(session), TrackingConfig.fast() if args.config == "fast" else TrackingConfig())
    times["tracking_s"] = time.perf_counter() - t
    t = time.perf_counter()
    inp = inputs_from_tracking(session, tr, tr.visible_points_O, session.mass)
    times["contact_inputs_s"] = time.perf_counter() - t
    cfg = ContactConfig.fast() if args.config == "fast" else ContactConfig()
    if args.contact_epochs:
        cfg = dataclasses.replace(cfg, epochs=args.contact_epochs)
    t = time.perf_counter()
    c0 = time.process_time()
    out = run(inp, cfg)
    times["contact_s"] = time.perf_counter() - t
    cpu_contact = time.process_time() - c0
    m = out.metrics
    Vl = np.asarray(out.physible_mesh.vertices)
    Vt = np.asarray(make_object(spec.object).mesh.vertices)
    n_tr = int(m["transitions"])
    n_vis = 0 if inp.visible_points_O is None else len(inp.visible_points_O)
    print(f"session {args.preset} ({spec.object}/{spec.interaction}, seed {args.seed}), config {args.config}: "
          f"{n_tr} transitions in {len(inp.states)} stretch(es), {n_vis} visible points, "
          f"{0 if inp.init_vertices_O is None else len(inp.init_vertices_O)} initial vertices")
    print("phases: " + ", ".join(f"{k[:-2]} {v:.1f} s" for k, v in times.items()))
    print(f"contact: {m['wall_time_s']:.1f} s = setup+pre-fit {m['time_setup_pretrain_s']:.1f} s + training "
          f"{m['time_train_s']:.1f} s ({int(m['time_epochs'])}/{cfg.epochs} epochs, best {int(m['best_epoch'])}, "
          f"{m['time_s_per_epoch']:.3f} s/epoch; solver {m['time_solver_s']:.1f} s, hull+closest points "
          f"{m['time_hull_s']:.1f} s, forward/backward {m['time_forward_backward_s']:.1f} s) + final pass "
          f"{m['time_final_pass_s']:.1f} s; torch threads in the stage {cfg.threads}; CPU time of the stage "
          f"{cpu_contact:.1f} s")
    print(f"learned extents {np.round(np.ptp(Vl, axis=0), 3)} m, true object extents {np.round(np.ptp(Vt, axis=0), 3)} m "
          f"(the object frame of tracking is not the mesh frame: compare sizes only)")
    return {**times, "contact_cpu_s": cpu_contact, **{f"contact_{k}": v for k, v in m.items()}, "learned_extents_m": np.ptp(Vl, axis=0).tolist(),
            "true_extents_m": np.ptp(Vt, axis=0).tolist()}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("what", choices=["cube", "tagslam", "speed", "synth", "pipeline-input"])
    ap.add_argument("--preset", default="full", choices=["tiny", "small", "full"], help="pipeline-input: session size")
    ap.add_argument("--config", default="default", choices=["fast", "default"], help="pipeline-input: stage presets")
    ap.add_argument("--seed", type=int, default=3, help="pipeline-input: synthetic session seed")
    ap.add_argument("--contact-epochs", type=int, default=0, help="pipeline-input: override the preset's epochs")
    ap.add_argument("--sizes", type=int, nargs="+", default=[2, 4, 8, 16, 32])
    ap.add_argument("--steps", type=int, default=400, help="Adam steps per training run (epochs derived)")
    ap.add_argument("--epochs", type=int, default=300)
    ap.add_argument("--heldout", type=int, default=30)
    ap.add_argument("--batch", type=int, default=200)
    ap.add_argument("--width", type=int, default=64)
    ap.add_argument("--mu", type=float, default=0.26)
    ap.add_argument("--w-pen", type=float, default=50.0, help="penetration weight (PLL: 0.5; see docs/contact.md)")
    ap.add_argument("--geometry", default=None, choices=["dsf", "polytope"],
                    help="deep support function or learnable polytope vertices (default: polytope for the tosses "
                         "= ContactConfig.tosses(), dsf for synth)")
    ap.add_argument("--learn-friction", action="store_true")
    ap.add_argument("--table-height", type=float, default=0.0,
                    help="cube: table plane height in the data's world frame (m) for learning and rollouts")
    ap.add_argument("--overrides", default=None, help='synth: JSON overrides of ContactConfig, e.g. \'{"w_com_centroid": 10}\'')
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None, help="write the figures as JSON")
    args = ap.parse_args()
    args.overrides = stage_overrides(ap, args.overrides, "--overrides", "contact")
    if args.threads:
        torch.set_num_threads(args.threads)
    print("command: python benchmarks/contact.py " + " ".join(sys.argv[1:]))
    fn = {"cube": bench_cube, "tagslam": bench_tagslam, "speed": bench_speed, "synth": bench_synth,
          "pipeline-input": bench_pipeline_input}[args.what]
    res = fn(args)
    if args.out:
        args.out.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
