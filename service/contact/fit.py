"""Training loop and the stage entry point ``run`` of contact-implicit learning (see ``learn.py`` for the loss).

Per epoch: export the detached hull once (only if a sphere contact or the vision term needs it) and compute
on it the outward directions toward all sphere centres and all visible points; shuffle the transitions; for
each batch solve the impulse problem (warm-started from the impulses of the previous epoch) and take one Adam
step on the loss at the optimum. Stop early on a plateau of the epoch loss; the parameters of the epoch with
the lowest mean loss are kept. Afterwards every transition is run once more to get impulses, residuals and the
physible set.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch

from service.contact.learn import (
    ContactModel,
    LossWeights,
    Transitions,
    build_model,
    contact_loss,
    export,
    vision_directions,
    vision_loss,
)
from service.contact.geometry import outward_directions_to
from service.contact.inertia import com_centroid_penalty, enclosing_ellipsoid, realizability_ratio, solid_hull_inertia
from service.contact.solver import SolverSettings
from service.contact.types import ContactConfig, ContactInputs, ContactOutputs, StepResiduals
from service.errors import StageFailed
from service.mesh import Mesh
from service.session.types import Friction

Progress = Callable[[float, str], None] | None


@dataclass
class TrainResult:
    loss_history: np.ndarray
    best_epoch: int
    timings: dict = field(default_factory=dict)


def _weights(cfg: ContactConfig) -> LossWeights:
    return LossWeights(cfg.w_pred, cfg.w_comp, cfg.w_diss, cfg.w_pen, cfg.w_vision, cfg.w_pen_ee)


def _solver(cfg: ContactConfig, iters: int | None = None) -> SolverSettings:
    return SolverSettings(max_iters=iters or cfg.solver_max_iters, eps_rel=cfg.solver_eps_rel, eps_abs=1e-8)


def train(model: ContactModel, tr: Transitions, dt: float, cfg: ContactConfig, *, ee_radius: float = 0.0,
          visible_points: np.ndarray | None = None, progress: Progress = None) -> TrainResult:
    """Adam on the violation-implicit loss; leaves ``model`` at the best epoch's parameters.

    The detached hull is exported once per epoch; the sphere directions of all transitions and the vision
    directions n̂ᵥ are computed on it then (the sphere centres in O and V are data, independent of θ). Training
    stops early when the epoch loss has not improved by ``cfg.plateau_rel_tol`` (relative) for
    ``cfg.patience`` epochs (after at least ``cfg.min_epochs``)."""
    w = _weights(cfg)
    gen = torch.Generator().manual_seed(cfg.seed + 1)
    perm_rng = np.random.default_rng(cfg.seed)
    geo = [p for p in model.geometry.parameters() if p.requires_grad]
    other = [p for n, p in model.named_parameters() if p.requires_grad and not n.startswith("geometry.")]
    opt = torch.optim.Adam([{"params": geo, "lr": cfg.lr}, {"params": other, "lr": cfg.lr_inertia}])
    n_batches = max(1, -(-len(tr) // cfg.batch_size))
    total_steps = max(1, cfg.epochs * n_batches)
    # cosine decay to lr_final_fraction·lr: the loss has a kink at the true surface (complementarity penalises
    # shrinking much more than penetration penalises growing), so constant-lr Adam noise drifts outward
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda k: cfg.lr_final_fraction + (1 - cfg.lr_final_fraction) * 0.5 * (1 + np.cos(np.pi * min(k, total_steps) / total_steps)))
    S = len(tr)
    V = None
    if visible_points is not None and len(visible_points) > 0 and w.vision > 0:
        Vn = np.asarray(visible_points, float)
        if len(Vn) > cfg.max_vision_points:  # fixed random subset: the term is a mean over V
            Vn = Vn[np.random.default_rng(cfg.seed + 3).choice(len(Vn), cfg.max_vision_points, replace=False)]
        V = torch.as_tensor(Vn, dtype=torch.float64)
    need_hull = tr.ee_p is not None or V is not None
    c_O = None
    if tr.ee_p is not None:
        from service.contact.dynamics import quat_to_mat
        from service.contact.learn import sphere_centres_O

        c_O = sphere_centres_O(quat_to_mat(tr.quat_next), tr.p_next, tr.ee_p)
    lam_cache: torch.Tensor | None = None
    history = []
    best = (np.inf, -1, copy.deepcopy(model.state_dict()))
    ref_best, since = np.inf, 0
    t_solver = t_total = t_hull = 0.0
    n_solved = 0
    for ep in range(cfg.epochs):
        order = perm_rng.permutation(S)
        tot, cnt = 0.0, 0
        th = time.perf_counter()
        ee_dirs_all = n_vis = None
        if need_hull or cfg.w_realizable > 0 or cfg.w_com_centroid > 0:
            hull = export(model, cfg.export_grid)[0]
            if cfg.w_realizable > 0 or cfg.w_com_centroid > 0:  # the ellipsoid enclosing the current geometry
                e_np, A_np = enclosing_ellipsoid(hull.vertices)
                ell = (torch.as_tensor(e_np, dtype=torch.float64), torch.as_tensor(A_np, dtype=torch.float64))
            if cfg.w_com_centroid > 0:  # uniform-density centroid of the current (detached) hull
                c_hull = torch.as_tensor(solid_hull_inertia(hull.vertices, 1.0)[0], dtype=torch.float64)
            if c_O is not None:
                ee_dirs_all = torch.as_tensor(outward_directions_to(hull, c_O, cfg.closest_candidates)[2], dtype=torch.float64)
            if V is not None:
                n_vis = vision_directions(hull, V, cfg.closest_candidates)
        t_hull += time.perf_counter() - th
        t_total += time.perf_counter() - th
        for a in range(0, S, cfg.batch_size):
            t0 = time.perf_counter()
            idx = order[a : a + cfg.batch_size]
            it = torch.as_tensor(idx)
            batch = tr.take(idx)
            lam0 = None
            if cfg.warm_start and lam_cache is not None:
                lam0 = lam_cache[it]
            res = contact_loss(model, batch, dt, w, cfg.n_plane, gen, _solver(cfg), ee_radius, None, lam0,
                               None if ee_dirs_all is None else ee_dirs_all[it])
            if lam_cache is None:
                lam_cache = torch.zeros(S, res.lam.shape[1], dtype=torch.float64)
            lam_cache[it] = res.lam
            loss = res.loss
            if V is not None:
                loss = loss + w.vision * vision_loss(model, V, None, n_vis)
            if cfg.w_realizable > 0:
                loss = loss + cfg.w_realizable * (realizability_ratio(model.inertia, *ell) - 1.0).clamp_min(0.0) ** 2
            if cfg.w_com_centroid > 0:
                loss = loss + cfg.w_com_centroid * com_centroid_penalty(model.inertia.com, c_hull, ell[1])
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            t_solver += res.solver_time
            n_solved += len(idx)
            tot += float(loss.detach()) * len(idx)
            cnt += len(idx)
            t_total += time.perf_counter() - t0
        ep_loss = tot / max(cnt, 1)
        if not np.isfinite(ep_loss):
            raise StageFailed("contact", f"loss became non-finite at epoch {ep}")
        history.append(ep_loss)
        if ep_loss < best[0]:
            best = (ep_loss, ep, copy.deepcopy(model.state_dict()))
        if progress is not None:
            progress((ep + 1) / cfg.epochs, f"epoch {ep + 1}/{cfg.epochs} loss {ep_loss:.4g}")
        # plateau: no relative improvement of the best loss for `patience` epochs
        if ep_loss < ref_best * (1.0 - cfg.plateau_rel_tol):
            ref_best, since = ep_loss, 0
        else:
            since += 1
        if cfg.patience > 0 and ep + 1 >= cfg.min_epochs and since >= cfg.patience:
            break
    model.load_state_dict(best[2])
    n_ep = len(history)
    timings = {
        "train_s": t_total,
        "solver_s": t_solver,
        "hull_s": t_hull,
        "forward_backward_s": t_total - t_solver - t_hull,
        "epochs": n_ep,
        "s_per_epoch": t_total / max(n_ep, 1),
        "transitions_solved_per_s": n_solved / max(t_solver, 1e-9),
    }
    return TrainResult(np.asarray(history), best[1], timings)


@torch.no_grad()
def evaluate(model: ContactModel, tr: Transitions, dt: float, cfg: ContactConfig, *, ee_radius: float = 0.0,
             batch_size: int = 2000) -> dict:
    """Impulses, gaps and velocity residuals of every transition at the current parameters."""
    w = _weights(cfg)
    gen = torch.Generator().manual_seed(cfg.seed + 7)
    hull = export(model, cfg.export_grid)[0] if tr.ee_p is not None else None
    out: dict[str, list] = {k: [] for k in ("lam", "phi", "witness", "normal", "dv_obs", "dv_exp", "loss", "valid")}
    is_ee = None
    for a in range(0, len(tr), batch_size):
        idx = np.arange(a, min(a + batch_size, len(tr)))
        res = contact_loss(model, tr.take(idx), dt, w, cfg.n_plane, gen, _solver(cfg, 2 * cfg.solver_max_iters),
                           ee_radius, hull)
        nc = res.contacts.phi.shape[1]
        out["lam"].append(res.lam.reshape(-1, nc, 3))
        out["phi"].append(res.contacts.phi)
        out["witness"].append(res.contacts.witness_O)
        out["normal"].append(res.contacts.normal_O)
        out["dv_obs"].append(res.dv_observed)
        out["dv_exp"].append(res.dv_explained)
        out["loss"].append(res.per_sample)
        out["valid"].append(res.valid)
        is_ee = res.contacts.is_ee
    r = {k: torch.cat(v).numpy() for k, v in out.items()}
    r["is_ee"] = is_ee.numpy()
    return r


def physible_set(ev: dict, fraction: float, max_points: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(points (P,3), outward directions (P,3)) of contacts whose normal impulse is in the top ``fraction``."""
    lam_n = ev["lam"][..., 0].reshape(-1)
    W = ev["witness"].reshape(-1, 3)
    N = ev["normal"].reshape(-1, 3)
    if lam_n.size == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    thr = np.quantile(lam_n, 1.0 - fraction)
    keep = (lam_n > thr) & (lam_n > 0)
    P, D = W[keep], N[keep]
    if len(P) > max_points:
        sel = np.random.default_rng(seed).choice(len(P), max_points, replace=False)
        P, D = P[sel], D[sel]
    return P, D


def residuals_from(ev: dict, tr: Transitions) -> StepResiduals:
    is_ee = ev["is_ee"].astype(bool)
    lam_n = ev["lam"][..., 0]
    phi = ev["phi"]
    return StepResiduals(
        traj=tr.traj.astype(np.int64),
        step=tr.step.astype(np.int64),
        dv_observed=ev["dv_obs"],
        dv_explained=ev["dv_exp"],
        residual=ev["dv_obs"] - ev["dv_exp"],
        phi_table=phi[:, ~is_ee].min(-1),
        phi_ee=phi[:, is_ee][:, 0] if is_ee.any() else np.full(len(phi), np.inf),
        impulse_table=lam_n[:, ~is_ee].sum(-1),
        impulse_ee=lam_n[:, is_ee][:, 0] if is_ee.any() else np.zeros(len(phi)),
    )


def _check_inputs(inputs: ContactInputs) -> None:
    if not inputs.states:
        raise StageFailed("contact", "no trajectories")
    if not np.isfinite(inputs.dt) or inputs.dt <= 0:
        raise StageFailed("contact", f"dt must be positive, got {inputs.dt}")
    for k, X in enumerate(inputs.states):
        X = np.asarray(X)
        if X.ndim != 2 or X.shape[1] != 13:
            raise StageFailed("contact", f"trajectory {k}: states must be (T,13), got {X.shape}")
        if not np.isfinite(X).all():
            raise StageFailed("contact", f"trajectory {k}: non-finite state values")
        if inputs.ee_p_W is not None:
            if np.asarray(inputs.ee_p_W[k]).shape != (len(X), 3) or np.asarray(inputs.ee_v_W[k]).shape != (len(X), 3):
                raise StageFailed("contact", f"trajectory {k}: end-effector arrays must be ({len(X)},3)")
    if sum(max(len(X) - 1, 0) for X in inputs.states) < 1:
        raise StageFailed("contact", "no transitions (every trajectory has fewer than 2 states)")


def run(inputs: ContactInputs, cfg: ContactConfig, *, progress: Progress = None) -> ContactOutputs:
    """Learn geometry (deep support function), CoM and inertia from the trajectories (module docstrings).

    Runs with ``cfg.threads`` torch threads (restored afterwards): the batched ops here are small, and one
    thread is faster than two on a shared 2-core machine (docs/contact.md)."""
    _check_inputs(inputs)
    n_threads = torch.get_num_threads()
    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    try:
        return _run(inputs, cfg, progress)
    finally:
        torch.set_num_threads(n_threads)


def _run(inputs: ContactInputs, cfg: ContactConfig, progress: Progress) -> ContactOutputs:
    from service.contact.learn import make_transitions

    t_start = time.perf_counter()
    mass = float(inputs.mass) if inputs.mass and inputs.mass > 0 else cfg.default_mass
    tr = make_transitions(inputs.states, inputs.ee_p_W, inputs.ee_v_W, inputs.table_height)
    V = inputs.visible_points_O
    init = inputs.init_vertices_O
    if init is None and V is not None and len(V) >= 4:
        init = V
    model = build_model(mass, inputs.friction.object_table, inputs.friction.object_robot, init, width=cfg.width,
                        init_radius=cfg.init_radius, pretrain_steps=cfg.pretrain_steps, learn_com=cfg.learn_com,
                        learn_friction=cfg.learn_friction, learn_mass=cfg.learn_mass, seed=cfg.seed,
                        geometry=cfg.geometry, n_vertices=cfg.n_vertices)
    prog = (lambda f, m: progress(0.95 * f, m)) if progress is not None else None
    t0 = time.perf_counter()
    t_pretrain = t0 - t_start
    tres = train(model, tr, inputs.dt, cfg, ee_radius=inputs.ee_radius, visible_points=V, progress=prog)
    t1 = time.perf_counter()
    ev = evaluate(model, tr, inputs.dt, cfg, ee_radius=inputs.ee_radius)
    P, N = physible_set(ev, cfg.physible_fraction, cfg.max_physible_points, cfg.seed)
    mesh, dirs, spts = export(model, cfg.export_grid)
    t_final = time.perf_counter() - t1
    if mesh.is_empty:
        raise StageFailed("contact", "the learned support function gave an empty hull")
    with torch.no_grad():
        I = model.inertia.central_inertia().numpy()
        com = model.inertia.com.detach().numpy().copy()
        m = float(model.inertia.mass)
        mu = model.mu.detach().numpy()
        e_np, A_np = enclosing_ellipsoid(mesh.vertices)
        ratio = float(realizability_ratio(model.inertia, torch.as_tensor(e_np), torch.as_tensor(A_np)))
        c_hull = solid_hull_inertia(mesh.vertices, 1.0)[0]
    metrics = {
        # tr(A(Σ + δδᵀ)) for the ellipsoid enclosing the learned geometry: ≤ 1 when a mass inside it can have
        # this CoM and inertia (inertia.py)
        "inertia_realizability": ratio,
        # distance (m) of the learned CoM from the uniform-density centroid of the learned hull
        "com_centroid_offset_m": float(np.linalg.norm(com - c_hull)),
        "final_loss": float(tres.loss_history[-1]) if len(tres.loss_history) else float("nan"),
        "best_loss": float(tres.loss_history[tres.best_epoch]) if len(tres.loss_history) else float("nan"),
        "best_epoch": float(tres.best_epoch),
        "transitions": float(len(tr)),
        "physible_points": float(len(P)),
        "wall_time_s": time.perf_counter() - t_start,
        "time_setup_pretrain_s": t_pretrain,
        "time_final_pass_s": t_final,
        "mass_declared": float(bool(inputs.mass_declared)),
        **{f"time_{k}": float(v) for k, v in tres.timings.items()},
    }
    if progress is not None:
        progress(1.0, "contact learning done")
    return ContactOutputs(
        physible_mesh=mesh,
        mass=m,
        com_O=com,
        inertia_O=I,
        friction=Friction(float(mu[0]), float(mu[1])) if cfg.learn_friction else inputs.friction,
        physible_points_O=P,
        physible_normals_O=N,
        residuals=residuals_from(ev, tr),
        loss_history=tres.loss_history,
        support_directions=dirs,
        support_points=spts,
        metrics=metrics,
    )


def model_mesh(model: ContactModel, grid: int = 8) -> Mesh:
    return export(model, grid)[0]
