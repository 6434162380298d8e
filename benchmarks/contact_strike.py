"""Where contact learning puts the end-effector contacts of strike sessions, against the true shape (diagnosis).

Reads a flow data folder (the ``data`` folder of ``benchmarks/residuals_pipeline.py --work DIR``: stored tracking and
contact outputs per session) and, per session whose ingest name matches, re-runs the contact stage on the stored
tracking outputs (or on the true poses, ``--poses true``) with ``ContactConfig()`` plus ``--config`` overrides. The
true shape (``ground_truth/``, expressed in the tracker's frame O by the mean tracked-to-true frame offset, as
``residuals_pipeline.py --diagnose`` does) is read here only, to measure:

- the physible end-effector points (not table contacts): how far outside the true shape they lie (mm), all and the
  distinct ones (rounded to 0.1 mm);
- for the transitions k -> k+1 that produced them: the gap between the sphere and the true shape at the step end
  (camera frame k+1, what the contact term of the implicit formulation sees) and the smallest gap along the robot
  log's path within the step (the sphere's closest approach, object pose interpolated between the frames);
- the learned hull's support excess over the true shape along the box's horizontal sides and its volume.

    python benchmarks/contact_strike.py /tmp/rp/w/data --name baking_box_strike_511 [--session SHA_PREFIX]
        [--poses tracked|true] [--config '{"w_pen_ee": 50}'] [--stored] [--list]

``--stored`` only analyses the stored contact outputs (end-effector points told apart from table contacts by
``service.fusion.stage.table_contacts``), without re-running.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import resource
import sys
import time
from pathlib import Path

import numpy as np
from _overrides import stage_overrides


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def box_distance(P_G: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(N,) signed distance of points (N,3) to the axis-aligned box [lo, hi] (positive outside)."""
    c, h = 0.5 * (lo + hi), 0.5 * (hi - lo)
    q = np.abs(P_G - c) - h
    out = np.linalg.norm(np.maximum(q, 0), axis=-1)
    return out + np.minimum(q.max(-1), 0)


def _interp_pose(X0: np.ndarray, X1: np.ndarray, s: float) -> np.ndarray:
    from service.transforms import so3_exp, so3_log

    X = np.eye(4)
    X[:3, :3] = X0[:3, :3] @ so3_exp(s * so3_log(X0[:3, :3].T @ X1[:3, :3]))
    X[:3, 3] = (1 - s) * X0[:3, 3] + s * X1[:3, 3]
    return X


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", type=Path)
    ap.add_argument("--name", default=None, help="ingest name (e.g. baking_box_strike_511)")
    ap.add_argument("--session", default=None, help="session sha256 prefix (several sessions share a name)")
    ap.add_argument("--poses", choices=("tracked", "true"), default="tracked",
                    help="poses the contact stage is re-run on: the tracked ones (what the service does) or, as an "
                         "oracle that isolates tracking errors, the true ones from ground_truth/ (diagnosis only: "
                         "nothing of that run is stored or shipped)")
    ap.add_argument("--config", default=None, help="JSON overrides of ContactConfig()")
    ap.add_argument("--stored", action="store_true", help="analyse the stored contact outputs only")
    ap.add_argument("--tracking", default=None, help="tracking artifact key prefix (default: the newest)")
    ap.add_argument("--list", action="store_true", help="print per end-effector point details")
    a = ap.parse_args()
    over = stage_overrides(ap, a.config, "--config", "contact")
    if not (a.data / "artifacts").is_dir():
        ap.error(f"{a.data}: not a pipeline data folder (no artifacts/ in it)")

    from service.contact import inputs_from_tracking
    from service.contact.fit import evaluate, physible_set, train
    from service.contact.learn import build_model, make_transitions
    from service.contact.types import ContactConfig, ContactOutputs
    from service.evaluation.ground_truth import load_ground_truth
    from service.fusion.stage import table_contacts
    from service.io import load_value
    from service.session import load_session
    from service.tracking.types import TrackingOutputs
    from service.tracking.velocity import velocities
    from service.transforms import X_inv, make_X

    cfg = ContactConfig(**over)
    art = a.data / "artifacts"

    def manifests(stage):
        return [json.loads(m.read_text()) for m in (art / stage).glob("*/manifest.json")]

    ingest = {m["key"]: m["metrics"] for m in manifests("ingest")}
    sessions = sorted({k for k, m in ingest.items() if (a.name is None or m.get("name") == a.name)
                       and (a.session is None or m["sha256"].startswith(a.session))})
    if not sessions:
        ap.error(f"{a.data}: no stored session matches --name {a.name} --session {a.session}")
    print(f"# python benchmarks/contact_strike.py {a.data}" + (f" --name {a.name}" if a.name else "")
          + (f" --session {a.session}" if a.session else "") + f" --poses {a.poses}"
          + (f" --config '{a.config}'" if a.config else "") + (" --stored" if a.stored else ""))
    for skey in sessions:
        meta = ingest[skey]
        cos = sorted([m for m in manifests("contact") if m["inputs"]["session"] == skey
                      and (a.tracking is None or m["inputs"]["tracking"].startswith(a.tracking))],
                     key=lambda m: m["created"])
        if not cos:
            continue
        cm = cos[-1]
        sdir = a.data / "sessions" / meta["sha256"]
        sess = load_session(sdir, meta["sha256"])
        tr = load_value(TrackingOutputs, art / "tracking" / cm["inputs"]["tracking"] / "value")
        gt = load_ground_truth(sdir)  # diagnosis only
        ok = np.asarray(tr.tracked, bool)
        Xs = np.stack([X_inv(tr.X_WO[k]) @ gt.X_WG[k] for k in np.flatnonzero(ok)])
        U, _, Vt = np.linalg.svd(Xs[:, :3, :3].sum(0))
        X_OG = make_X(U @ Vt, Xs[:, :3, 3].mean(0))
        X_GO = X_inv(X_OG)
        VG = np.asarray(gt.mesh.vertices)
        lo, hi = VG.min(0), VG.max(0)

        def outside(P_O):
            P_G = (np.asarray(P_O) - X_OG[:3, 3]) @ X_OG[:3, :3]
            return box_distance(P_G, lo, hi)

        if a.poses == "true":
            X_use = gt.X_WG @ X_GO
            v, w = velocities(np.asarray(tr.t, float), X_use)
            tr_use = dataclasses.replace(tr, X_WO=X_use, v_WO_W=v, w_WO_O=w, tracked=np.ones(len(tr.t), bool))
        else:
            tr_use = tr
        t0, c0 = time.time(), _cpu()
        if a.stored:
            co = load_value(ContactOutputs, art / "contact" / cm["key"] / "value")
            P, N = co.physible_points_O, co.physible_normals_O
            tab = table_contacts(P, N, tr.X_WO, tr.tracked, sess.table_height)
            Pe, Ne = P[~tab], N[~tab]
            mesh = co.physible_mesh
            info = None
            print(f"{meta['name']} {meta['sha256'][:8]} stored contact {cm['key'][:10]} (tracking {cm['inputs']['tracking'][:10]})")
        else:
            inputs = inputs_from_tracking(sess, tr_use, tr_use.visible_points_O, sess.mass)
            import torch

            torch.set_num_threads(1)
            trn = make_transitions(inputs.states, inputs.ee_p_W, inputs.ee_v_W, inputs.table_height)

            mass = float(inputs.mass)
            init = inputs.init_vertices_O
            model = build_model(mass, inputs.friction.object_table, inputs.friction.object_robot, init,
                                width=cfg.width, init_radius=cfg.init_radius, pretrain_steps=cfg.pretrain_steps,
                                learn_com=cfg.learn_com, learn_friction=cfg.learn_friction,
                                learn_mass=cfg.learn_mass, seed=cfg.seed, geometry=cfg.geometry,
                                n_vertices=cfg.n_vertices)
            com_init = model.inertia.com.detach().numpy().copy()
            res = train(model, trn, inputs.dt, cfg, ee_radius=inputs.ee_radius, visible_points=inputs.visible_points_O)
            ev = evaluate(model, trn, inputs.dt, cfg, ee_radius=inputs.ee_radius)
            P, N = physible_set(ev, cfg.physible_fraction, cfg.max_physible_points, cfg.seed)
            lam_n = ev["lam"][..., 0]
            thr = np.quantile(lam_n.reshape(-1), 1.0 - cfg.physible_fraction)
            is_ee = ev["is_ee"].astype(bool)
            sel = np.flatnonzero((lam_n[:, is_ee][:, 0] > thr) & (lam_n[:, is_ee][:, 0] > 0))
            Pe = ev["witness"][sel][:, is_ee][:, 0]
            Ne = ev["normal"][sel][:, is_ee][:, 0]
            from service.contact.learn import export

            mesh = export(model, cfg.export_grid)[0]
            info = (trn, sel, inputs, res)
            phi_ee = ev["phi"][sel][:, is_ee][:, 0] * 1e3
            if len(phi_ee):
                print(f"  learned gap phi of the sphere contact on those transitions (mm): median {np.median(phi_ee):.1f} "
                      f"[{phi_ee.min():.1f}, {phi_ee.max():.1f}]; all transitions: {(ev['phi'][:, is_ee][:, 0] < -0.003).sum()} "
                      f"with the sphere > 3 mm inside the learned shape")
            print(f"{meta['name']} {meta['sha256'][:8]} contact re-run on {a.poses} poses (tracking "
                  f"{cm['inputs']['tracking'][:10]}), {len(trn)} transitions, {len(res.loss_history)} epochs "
                  f"(best epoch loss {res.loss_history[res.best_epoch]:.4g}; contact loss of the final pass "
                  f"{float(np.mean(ev['loss'])):.4g}), "
                  f"{time.time() - t0:.0f} s wall / {_cpu() - c0:.0f} s CPU")
        d = outside(Pe) * 1e3
        uniq = np.unique(np.round(Pe, 4), axis=0)
        du = outside(uniq) * 1e3
        print(f"  end-effector physible points: {len(Pe)} ({len(uniq)} distinct) of {len(P)}; outside the true shape "
              f"(mm): min {d.min() if len(d) else np.nan:.1f} median {np.median(d) if len(d) else np.nan:.1f} "
              f"max {d.max() if len(d) else np.nan:.1f}; distinct: median {np.median(du) if len(du) else np.nan:.1f}, "
              f"> 3 mm: {(du > 3).sum()}")
        # learned hull vs the true box: support excess along the box's horizontal sides and +z, hull volume
        import trimesh

        HV = np.asarray(mesh.vertices)
        HG = (HV - X_OG[:3, 3]) @ X_OG[:3, :3]
        exc = [(HG[:, 0].min() * -1 + lo[0]) * 1e3, (HG[:, 0].max() - hi[0]) * 1e3,
               (-HG[:, 1].min() + lo[1]) * 1e3, (HG[:, 1].max() - hi[1]) * 1e3, (HG[:, 2].max() - hi[2]) * 1e3]
        print(f"  learned hull {trimesh.convex.convex_hull(HV).volume * 1e3:.3f} L (true "
              f"{np.prod(hi - lo) * 1e3:.3f} L); support excess -x/+x/-y/+y/+z (mm) "
              + " / ".join(f"{e:.1f}" for e in exc))
        # centre of mass against the true one (the uniform true shape's centroid; ground truth, diagnosis only):
        # learned, the initial value (centroid of the initial geometry) and the uniform centroid of the learned hull
        from service.contact.inertia import solid_hull_inertia

        com_true_G = np.asarray(gt.mesh.to_trimesh().center_mass, float)

        def in_G(c_O):
            return (np.asarray(c_O, float) - X_OG[:3, 3]) @ X_OG[:3, :3]

        # the point the tracking errors of (Δv, Δω) rotate about: p minimising Σ‖δΔv + R(δΔω × p)‖² over transitions
        # (δ = tracked − true, both of O's origin); a CoM there hides that much of the error from the prediction term
        from service.tracking.velocity import velocities as _vel

        Xt = gt.X_WG @ X_GO
        vt, wt = _vel(np.asarray(tr.t, float), Xt)
        vv, ww = np.asarray(tr.v_WO_W), np.asarray(tr.w_WO_O)
        As, bs = [], []
        for k in np.flatnonzero(ok[1:] & ok[:-1]) + 1:
            dw = (ww[k] - ww[k - 1]) - (wt[k] - wt[k - 1])
            dv = (vv[k] - vv[k - 1]) - (vt[k] - vt[k - 1])
            As.append(Xt[k][:3, :3] @ np.array([[0, -dw[2], dw[1]], [dw[2], 0, -dw[0]], [-dw[1], dw[0], 0]]))
            bs.append(-dv)
        if As:
            A_, b_ = np.concatenate(As), np.concatenate(bs)
            piv = np.linalg.lstsq(A_, b_, rcond=None)[0]
            c_true_O = X_OG[:3, :3] @ com_true_G + X_OG[:3, 3]
            r2 = lambda c: float(np.mean(np.sum((A_ @ c - b_).reshape(-1, 3) ** 2, 1)))  # noqa: E731
            print("  tracking errors of (dv, dw) rotate about a point at " + " ".join(
                f"{x * 1e3:+.1f}" for x in ((piv - X_OG[:3, 3]) @ X_OG[:3, :3] - com_true_G))
                + f" mm from the true CoM (G axes); their mean squared CoM velocity error {r2(c_true_O):.3g} with the "
                f"true CoM, {r2(piv):.3g} at that point (m²/s²)")
        rows = [("hull centroid", solid_hull_inertia(HV, 1.0)[0])]
        if info is not None:
            lt = ev["lam"][..., 0][:, ~is_ee]  # table normal impulses (S,n_plane) and their witness points
            Wt = ev["witness"][:, ~is_ee]
            w_imp = (Wt * lt[..., None]).sum((0, 1)) / max(lt.sum(), 1e-12)
            rows = [("learned", model.inertia.com.detach().numpy()), ("initial", com_init),
                    ("table impulse centre", w_imp)] + rows
        elif a.stored:
            rows = [("learned", co.com_O)] + rows
        print("  CoM - true CoM in the true shape's axes (mm): " + "; ".join(
            f"{n} " + " ".join(f"{x * 1e3:+.1f}" for x in in_G(c) - com_true_G) + f" (|{np.linalg.norm(in_G(c) - com_true_G) * 1e3:.1f}|)"
            for n, c in rows) + f"; box half-extents (mm) " + " ".join(f"{x * 1e3:.1f}" for x in (hi - lo) / 2))
        if info is not None:
            # how strongly the data hold the CoM: the final pass's mean contact loss with only the CoM replaced
            import torch

            c_keep = model.inertia.com.detach().clone()
            parts = []
            for n, c in (("learned", c_keep.numpy()), ("hull centroid", rows[-1][1]),
                         ("true", X_OG[:3, :3] @ com_true_G + X_OG[:3, 3])):
                with torch.no_grad():
                    model.inertia.com.copy_(torch.as_tensor(np.asarray(c, float)))
                parts.append(f"{n} {float(np.mean(evaluate(model, trn, inputs.dt, cfg, ee_radius=inputs.ee_radius)['loss'])):.5g}")
            with torch.no_grad():
                model.inertia.com.copy_(c_keep)
            print("  mean contact loss with the CoM at: " + ", ".join(parts) + " (geometry and moments as learned)")
        if info is None:
            continue
        trn, sel, inputs, res = info
        # gaps of the sphere to the true shape: at the step end (frame k+1) and the closest along the robot log
        t = np.asarray(tr_use.t, float)
        X_true_O = gt.X_WG @ X_GO
        runs = _runs(np.asarray(tr_use.tracked, bool))
        gaps_end, gaps_min, gaps_used = [], [], []
        rt, rp = np.asarray(sess.robot_t, float), np.asarray(sess.robot_p_WE, float)
        for s in sel:
            ti, k = int(trn.traj[s]), int(trn.step[s])
            f0 = runs[ti][0] + k
            f1 = f0 + 1
            c1 = sess.p_WE[f1]
            g1 = outside((X_inv(X_true_O[f1]) @ np.append(c1, 1))[:3][None])[0] - sess.ee_radius
            m = (rt >= t[f0]) & (rt <= t[f1])
            gm = g1
            for tt, cc in zip(rt[m], rp[m]):
                Xo = _interp_pose(X_true_O[f0], X_true_O[f1], (tt - t[f0]) / (t[f1] - t[f0]))
                gm = min(gm, outside((X_inv(Xo) @ np.append(cc, 1))[:3][None])[0] - sess.ee_radius)
            # the sphere centre the loss used, in the object frame of the poses the loss used (tracked or true)
            cu = trn.ee_p[s].numpy() + np.array([0, 0, inputs.table_height])
            gu = outside((X_inv(tr_use.X_WO[f1]) @ np.append(cu, 1))[:3][None])[0] - sess.ee_radius
            gaps_end.append(g1 * 1e3)
            gaps_min.append(gm * 1e3)
            gaps_used.append(gu * 1e3)
        ge, gmn, gus = map(np.asarray, (gaps_end, gaps_min, gaps_used))
        if len(ge):
            print(f"  their transitions: true sphere gap at the step end (mm) median {np.median(ge):.1f} "
                  f"[{ge.min():.1f}, {ge.max():.1f}]; closest along the robot log median {np.median(gmn):.1f} "
                  f"[{gmn.min():.1f}, {gmn.max():.1f}]; sphere the loss used, against the true shape in the frame of the poses used: median {np.median(gus):.1f}; "
                  f"corr(point outside, that gap) {np.corrcoef(d, gus)[0, 1] if len(d) > 2 else np.nan:.2f}")
        if a.list:
            for i, s in enumerate(sel):
                print(f"    traj {int(trn.traj[s])} step {int(trn.step[s])}: outside {d[i]:.1f} mm, phi {phi_ee[i]:.1f}, gap end "
                      f"{ge[i]:.1f}, closest {gmn[i]:.1f}, used {gus[i]:.1f}")
        sys.stdout.flush()


def _runs(tracked: np.ndarray, min_len: int = 3) -> list[tuple[int, int]]:
    from service.contact.data import _split_tracked

    return _split_tracked(tracked, min_len)


if __name__ == "__main__":
    main()
