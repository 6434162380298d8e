"""K-fold cross-fitting of the residual loop's held-out test (``ResidualConfig.folds`` = K >= 2).

The units (whole trajectories when >= 4 have blocks, else the time blocks of the session) are shuffled (seeded)
and dealt into K folds, so every unit is held out exactly once. For fold f the nuisance corrections (§3b), each
candidate θ_f and the joint refit are fitted on the blocks of the other K − 1 folds only, and fold f's held-out
blocks are rolled out with fold f's models; the acceptance rules 1–7 (``loop._decide``, rule 6 on all frames,
bounds, resolution, direction) are applied once to the union over folds of the held-out block errors before /
after, with units pooled over folds (U and the number of held-out blocks cover all units instead of
``heldout_fraction`` of them: twice one split's at the default 0.5). No held-out error comes from a fit that saw
its unit.

The one split (``folds`` = 1, ``loop.split_segments``) runs the same loop (``crossfit``) as a single fold: the
same rules and records, without what only K >= 2 has (the fold values in the reasons, rule 8, the per-fold
records ``by_mode["folds"]``, ``by_mode["rounds"][i]["folds"]``, ``by_mode["refit"]``, and the final refit).

Greedy rounds: each fold keeps its own current model (its corrected base + the accepted effects with its own
θ_f); a candidate of round r is fitted on top of that fold's model. Rules 4 (resolution) and 7 (direction) are
checked on the fold mean θ̄ = mean_f θ_f, rule 5 (bound) on every θ_f (one fold pinned to a bound is compensation);
rule 8 (``fold_agreement``, K >= 2 only): every θ_f departs from the null value the same way (scalars: same sign
of θ_f − θ_null; vectors: every pairwise angle between the departures, scaled by the resolution, < 90°), or the
folds are fitting noise differently rather than seeing one effect. Cross-validation decides;
the parameter reported for an accepted effect (``ResidualOutputs.effects``, the candidate's ``params``, the output
model and URDF) is one more fit on all units (``final_refit``: the routine of one split, corrections included, the
accepted effects refitted jointly, training cap K × ``max_train_segments``), with θ̄ and the fold values reported
beside it (``by_mode["refit"]``, the candidate's reason): each θ_f saw only K − 1 folds' units, capped at
``max_train_segments`` blocks (on toss seed 8 the two fold fits of an angular damping of 2.0 /s gave 3.90 and
2.50 /s). Nuisance corrections are reported as their fold mean (the refit's in ``by_mode["refit"]``), never
applied to the output model (as with one split).

Cost: K fits per candidate per round (each on at most ``max_train_segments`` blocks, as one split's) and every
block rolled out once per candidate as held-out: ≈ K × one split's rollouts (2× for K = 2); plus the final refit
(one nuisance fit and about one candidate's K fits per accepted effect).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from service.errors import InvalidInput
from service.model import ObjectModel
from service.residuals.effects import (
    REGISTRY, SLIDE_EFFECTS, apply_effects, at_bound, fold_into_model, is_negligible, null_params,
)
from service.residuals.modes import classify
from service.residuals.types import EffectCandidate, ResidualConfig, ResidualInputs, ResidualOutputs


def fold_segments(segs: list, cfg: ResidualConfig) -> tuple[list[tuple[list, list]], list[np.ndarray]]:
    """Seeded K-fold partition: [(train_f, held_f)], [units_f] with units global ids (trajectory index, or the
    block's index in ``segs`` for one session). Every unit is in exactly one held-out fold; each fold's held-out
    list is capped at ``max_heldout_segments`` by random subsampling (as one split's)."""
    rng = np.random.default_rng(cfg.seed)
    k = cfg.folds
    by_traj = len({s.traj for s in segs}) >= 4
    if by_traj:
        trajs = sorted({s.traj for s in segs})
        if len(trajs) < k:
            raise InvalidInput("ResidualConfig.folds", f"{k} folds need >= {k} trajectories with blocks, got {len(trajs)}")
        perm = rng.permutation(trajs)
        fold_of = {int(t): i % k for i, t in enumerate(perm)}
        fid = np.array([fold_of[s.traj] for s in segs])
        uid = np.array([s.traj for s in segs])
    else:
        if len(segs) < k:
            raise InvalidInput("ResidualConfig.folds", f"{k} folds need >= {k} rollout blocks, got {len(segs)}")
        perm = rng.permutation(len(segs))
        fid = np.empty(len(segs), int)
        fid[perm] = np.arange(len(segs)) % k
        uid = np.arange(len(segs))
    parts, units = [], []
    for f in range(k):
        held_i = np.flatnonzero(fid == f)
        train = [segs[i] for i in np.flatnonzero(fid != f)]
        if len(held_i) > cfg.max_heldout_segments:
            held_i = np.sort(rng.choice(held_i, cfg.max_heldout_segments, replace=False))
        parts.append((train, [segs[i] for i in held_i]))
        units.append(uid[held_i])
    return parts, units


@dataclass
class _Fold:
    """One fold's state: its training pool and held-out blocks, its corrected base and accepted effects."""

    train: list
    held: list
    units: np.ndarray
    model: ObjectModel = None
    base_effects: dict = field(default_factory=dict)
    nuis_fix: dict = field(default_factory=dict)
    tr_n: list = field(default_factory=list)
    chosen: dict = field(default_factory=dict)
    held_frames0: list = field(default_factory=list)
    cur_frames: list = field(default_factory=list)
    nuisance: dict = field(default_factory=dict)
    gap_segs: list = field(default_factory=list)  # the training blocks with the input model's modes (contact-gap term)
    release: dict | None = None  # its held-out and training release blocks (``release_blocks``), cut when first needed


def _flat(names_theta: dict) -> dict[str, float]:
    return {k: float(v) for n, th in names_theta.items() for k, v in zip(REGISTRY[n].params, th)}


def fold_agreement(eff, thetas, model: ObjectModel) -> tuple[bool, str]:
    """Rule 8 (§4): do the K fold fits see the same effect? Departures d_f = (θ_f − θ_null) / resolution
    (per parameter, so the test does not depend on the parameters' units), θ_null from ``null_params``.
    One parameter: every d_f has the same sign (none exactly 0). Several (table tilt, CoM offset): every pairwise
    angle between the departures is < 90°, i.e. every d_f · d_g > 0 (none of zero norm): the folds' effects point
    into the same half-space of each other. ``thetas`` (K, P). Returns (agree, text for the reason)."""
    th = np.atleast_2d(np.asarray(thetas, float))
    null = np.asarray(null_params(eff, model), float)
    res = np.asarray(eff.resolution or (1.0,) * len(null), float)
    d = (th - null) / np.where(res > 0, res, 1.0)
    if d.shape[1] == 1:
        s = np.sign(d[:, 0])
        agree = bool(np.all(s == s[0]) and s[0] != 0)
        txt = "fold departures from no effect " + ", ".join(f"{v * res[0]:+.3g}" for v in d[:, 0]) + (
            " (same sign)" if agree else " (a fold on no effect)" if np.any(s == 0) else " (not all the same sign)")
        return agree, txt
    n = np.linalg.norm(d, axis=1)
    ang = []
    for a in range(len(d)):
        for b in range(a + 1, len(d)):
            c = float(d[a] @ d[b] / max(n[a] * n[b], 1e-300))
            ang.append(float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))) if n[a] > 0 and n[b] > 0 else 180.0)
    worst = max(ang)
    agree = worst < 90.0
    txt = f"largest angle between fold departures {worst:.1f}°" + (" (< 90°)" if agree else " (>= 90°)")
    return agree, txt


def agreement_rule(ok: bool, why: str, eff, thetas, model: ObjectModel) -> tuple[bool, str]:
    """Rule 8 after rules 1–7 (K >= 2 only): an effect passing them is rejected when its fold values disagree
    (``fold_agreement``); the test's figures are appended to the reason either way."""
    if len(np.atleast_2d(thetas)) < 2:
        return ok, why
    agree, txt = fold_agreement(eff, thetas, model)
    if ok and not agree:
        return False, f"rejected: the folds disagree on the effect ({txt}); " + why.removeprefix("passes; ")
    return ok, f"{why}; fold agreement: {txt}"


def _judge_lookalikes(round_res: list[tuple], final: dict, history: list, rnd: int, judge) -> list[tuple]:
    """Every passing candidate of ``round_res`` against each of its look-alikes fitted in the same round, in order:
    ``judge(cand, its Effect, look-alike name, its per-fold figures, the look-alike's)`` returns (still passing, new
    reason); the verdict is recorded (``_record``) and the first failing one ends the candidate's checks."""
    by_name = {r[2].effect: r for r in round_res}
    out = []
    for r in round_res:
        ok, gain, cand, per, theta_rep = r
        if ok:
            ea = REGISTRY[cand.effect]
            for other in ea.lookalikes:
                if other not in by_name:
                    continue
                ok, why = judge(cand, ea, other, per, by_name[other][3])
                cand = _record(cand, why, ok, final, history, rnd)
                if not ok:
                    break
        out.append((ok, gain, cand, per, theta_rep))
    return out


def _record(cand, why: str, ok: bool, final: dict, history: list, rnd: int):
    """The candidate with its new reason ``why``, written to ``final`` and to its entry of round ``rnd`` in
    ``history`` (with ``passes`` = ``ok``)."""
    cand = dataclasses.replace(cand, reason=why)
    final[cand.effect] = cand
    for h in history:
        if h["round"] == rnd + 1 and h["effect"] == cand.effect:
            h.update(passes=ok, reason=why)
    return cand


def shared_component(a, b) -> str:
    """The error component (``Effect.component``) two effects both act on: their common one, the narrower one when one
    of them acts on "both" (friction "both", linear damping "position": the position), else "both"."""
    if a.component == b.component:
        return a.component
    if a.component == "both":
        return b.component
    if b.component == "both":
        return a.component
    return "both"


def _lookalike_blocks(per_a, per_b, folds: list, ea, eb, component: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Paired held-out block errors of two effects' fold models on every held-out block of every fold where either
    acts: each block's mean over all its tracked frames of ``component``, (S,) for A, (S,) for B, and the units (S,)."""
    from service.residuals.loop import _acts_on, reduce_blocks

    e_a, e_b, u = [], [], []
    for f, fd in enumerate(folds):
        idx = [i for i, sg in enumerate(fd.held) if _acts_on(sg, ea) or _acts_on(sg, eb)]
        e_a.append(reduce_blocks([per_a[f]["after_frames"][i] for i in idx], component=component))
        e_b.append(reduce_blocks([per_b[f]["after_frames"][i] for i in idx], component=component))
        u.append(fd.units[np.asarray(idx, int)])
    e_a, e_b, u = np.concatenate(e_a), np.concatenate(e_b), np.concatenate(u)
    keep = np.isfinite(e_a) & np.isfinite(e_b)
    return e_a[keep], e_b[keep], u[keep]


def lookalike_refutation(round_res: list[tuple], folds: list, cfg: ResidualConfig, final: dict, history: list,
                         rnd: int) -> list[tuple]:
    """Rule 9b (§4, ``ResidualConfig.lookalike_refute``): a candidate A that passes the earlier rules is rejected when
    a look-alike B (``Effect.lookalikes``) fitted in the same round (passing or not) predicts the held-out blocks
    better beyond noise on the error component both act on (``shared_component``; friction against damping: the
    position |Δp|), over all the frames of the held-out blocks of every fold where A or B acts (a launch block's rest
    frames hold where the slide stopped), B's fold models against A's (``loop.head_to_head``: rules 2 and 3 with A
    in place of "before"). When neither is better beyond noise nothing changes (the greedy pick decides, as without
    the rule). ``round_res`` entries are (passes, all-frame fall, candidate, per-fold figures, θ̄); the refuted
    ones are returned with passes False, and their reasons in ``final`` and ``history`` say why."""
    from service.residuals.loop import head_to_head

    rng = np.random.default_rng(cfg.seed + 9002)  # its own stream: the main loop's draws stay as they were

    def judge(cand, ea, other, per, per_b):
        eb = REGISTRY[other]
        comp = shared_component(ea, eb)
        e_a, e_b, u = _lookalike_blocks(per, per_b, folds, ea, eb, comp)
        refuted, txt = head_to_head(e_a, e_b, u, cfg, rng) if len(e_a) >= 2 else (
            False, f"{len(e_a)} held-out block(s) to compare")
        txt = f"{comp} error, {other} against it: {txt}"
        if refuted:
            return False, (f"rejected: its look-alike {other} predicts the held-out blocks better ({txt}); "
                           + cand.reason.removeprefix("passes; "))
        return True, f"{cand.reason}; not refuted by its look-alike {other} ({txt})"

    return _judge_lookalikes(round_res, final, history, rnd, judge)


def release_blocks(fd, cfg: ResidualConfig, train: bool = False) -> list:
    """The release blocks (``loop.release_segment``, ``cfg.release_blocks`` frames after the release, the start state's
    polynomial of degree ``cfg.release_blocks_degree``) of fold ``fd``'s held-out launch blocks (``train``: of its
    training launch blocks), with the fold's modes; cut once per fold and kept on it."""
    from service.residuals.loop import release_segment

    if fd.release is None:
        fd.release = {}
    key = "train" if train else "held"
    if key not in fd.release:
        fd.release[key] = [r for r in (release_segment(sg, cfg.release_blocks, cfg, cfg.release_blocks_degree)
                                       for sg in (fd.train if train else fd.held)) if r is not None]
    return fd.release[key]


def fit_on_release(eff, guess, model: ObjectModel, base_effects: dict, chosen: dict, ev, launch_blocks: list,
                   gap: int, cfg: ResidualConfig, cap: int) -> tuple[tuple | None, int]:
    """``ResidualConfig.release_value``: the effect's value fitted (``loop._fit``, on its own frames) on the release
    blocks (``loop.release_segment``, ``gap`` frames after the release) of ``launch_blocks``, on top of ``model`` /
    ``base_effects`` and the other effects ``chosen``; at most ``cap`` blocks (a seeded draw). Returns (θ, number of
    release blocks used), θ None with fewer than 2 release blocks where the effect acts."""
    from service.residuals.loop import _acts_on, _fit, release_segment

    tr = [r for r in (release_segment(sg, gap, cfg, cfg.release_value_degree) for sg in launch_blocks)
          if r is not None and _acts_on(r, eff)]
    if len(tr) > cap:
        sub = np.random.default_rng(cfg.seed + 4244).choice(len(tr), cap, replace=False)
        tr = [tr[j] for j in sorted(sub)]
    if len(tr) < 2:
        return None, len(tr)
    theta, _ = _fit(eff, guess, model, base_effects, chosen, ev, tr, cfg)
    return eff.clip(theta), len(tr)


def release_value_folds(eff, per: list, folds: list, input_model: ObjectModel, input_effects: dict, ev,
                        cfg: ResidualConfig) -> dict:
    """``ResidualConfig.release_value``, for an accepted slide effect: each fold's value fitted on its training release
    blocks (``fit_on_release``, on the fold's model as accepted: its corrections, refitted with the effect when they
    were, and its earlier effects), and the held-out error where the effect acts (issue #6's criterion 3: its
    component on its frames of the held-out blocks where it acts, per block, then the mean) at those values. A fold
    with fewer than 2 release blocks keeps its launch-block value. ``per`` holds each fold's figures of the
    candidate's round (``theta``, ``nuis``, ``ho_idx``, ``ho_masks``). The fold models are not changed."""
    from service.residuals.loop import reduce_blocks

    vals, acting, n_rel, kept = [], [], [], []
    for f, (p, fd) in enumerate(zip(per, folds)):
        if p["nuis"]:
            m_c, fix_sim = apply_effects(input_model, p["nuis"])
            b_c = {**input_effects, **fix_sim}
        else:
            m_c, b_c = fd.model, fd.base_effects
        theta, n = fit_on_release(eff, p["theta"], m_c, b_c, fd.chosen, ev, fd.train, cfg.release_value, cfg,
                                  cfg.max_train_segments)
        n_rel.append(n)
        if theta is None:
            theta = tuple(p["theta"])
            kept.append(f + 1)
        vals.append(tuple(float(v) for v in theta))
        m_a, s_a = apply_effects(m_c, {**fd.chosen, eff.name: theta})
        held = [fd.held[i] for i in p["ho_idx"]]
        acting.append(reduce_blocks(ev.frame_split(m_a, {**b_c, **s_a}, held), p["ho_masks"], eff.component))
    acting = np.concatenate(acting) if acting else np.zeros(0)
    return {"folds": vals, "fold_mean": eff.clip(tuple(np.mean(np.array(vals, float), 0))), "release_blocks": n_rel,
            "launch_value_kept": kept, "heldout_acting_after": float(np.nanmean(acting)) if len(acting) else float("nan")}


def release_fit_value(eff, fd, cfg: ResidualConfig, ev, guess) -> tuple:
    """``ResidualConfig.release_fit``: the effect's value fitted on fold ``fd``'s training release blocks alone (from
    the fold's current model: its corrections and accepted effects; ``loop._fit`` on the effect's frames of those
    blocks), or None with fewer than 2 such blocks."""
    from service.residuals.loop import _acts_on, _fit

    tr = [r for r in release_blocks(fd, cfg, train=True) if _acts_on(r, eff)]
    if len(tr) < 2:
        return None
    theta, _ = _fit(eff, guess, fd.model, fd.base_effects, fd.chosen, ev, tr, cfg)
    return theta


def release_rule(ok: bool, why: str, eff, per: list, folds: list, cur: list, ev, cfg: ResidualConfig) -> tuple[bool, str]:
    """Rule 10 (§4, ``ResidualConfig.release_blocks``): a slide effect must also improve the slide alone. On the
    held-out release blocks of every fold (``release_blocks``: started after the sphere stopped pushing, so the struck
    size, the strike's timing and the sphere contact are in the start state), each block's mean of the effect's
    error component over all its tracked frames (the slide and where it stopped), the fold's current model (before)
    against the candidate's fold model (after, with its own corrections when it was refitted with them). A candidate
    passing rules 1-8 is rejected unless the mean error falls and more blocks get better than worse (by more than
    ``tie_tol_rel`` of the median error before, as in the sign test: a value at "no effect" changes nothing); with fewer than
    ``release_min_blocks`` release blocks the rule does not judge. The figures are appended to the reason either way.
    ``per`` holds each fold's ``after_model`` (model, simulator effects), ``cur`` each fold's current (model, effects)."""
    from service.residuals.loop import reduce_blocks

    b, a, vals = [], [], []
    for f, fd in enumerate(folds):
        rel = release_blocks(fd, cfg)
        if not rel:
            continue
        cm, cs = cur[f]
        m_after, e_after = per[f]["after_model"]
        if cfg.release_fit:
            theta = release_fit_value(eff, fd, cfg, ev, per[f]["theta"])
            if theta is None:
                continue
            vals.append(theta)
            m_after, s_after = apply_effects(fd.model, {**fd.chosen, eff.name: theta})
            e_after = {**fd.base_effects, **s_after}
        b.append(reduce_blocks(ev.frame_split(cm, {**fd.base_effects, **cs}, rel), component=eff.component))
        a.append(reduce_blocks(ev.frame_split(m_after, e_after, rel), component=eff.component))
    b = np.concatenate(b) if b else np.zeros(0)
    a = np.concatenate(a) if a else np.zeros(0)
    keep = np.isfinite(b) & np.isfinite(a)
    b, a = b[keep], a[keep]
    if len(b) < cfg.release_min_blocks:
        return ok, f"{why}; release blocks: {len(b)}, too few to judge"
    fall = float((b.mean() - a.mean()) / b.mean()) if b.mean() > 0 else 0.0
    tol = cfg.tie_tol_rel * float(np.median(b))  # ties as in the sign test (rule 3)
    n_b, n_w = int(np.sum(b - a > tol)), int(np.sum(a - b > tol))
    txt = (f"release blocks ({eff.component}): {b.mean() * 1e3:.2f} -> {a.mean() * 1e3:.2f} mm ({fall:+.1%}), "
           f"better/worse on {n_b}/{n_w} of {len(b)}")
    if vals:
        txt += ", at the values fitted on the folds' training release blocks " + " / ".join(
            "(" + ", ".join(f"{v:.4g}" for v in th) + ")" for th in vals)
    if ok and not (fall > 0 and n_b > n_w):
        return False, f"rejected: does not improve the slide alone ({txt}); " + why.removeprefix("passes; ")
    return ok, f"{why}; {txt}"


def nuisance_blocks(train: list, f: int, cfg: ResidualConfig) -> list:
    """The training blocks of fold ``f`` (0-based) that the nuisance corrections are fitted on: all of ``train``, or
    ``cfg.max_nuisance_segments`` of them drawn without replacement (seeded by ``cfg.seed`` and the fold), in their
    order."""
    tr_n = list(train)
    if len(tr_n) > cfg.max_nuisance_segments:
        sub = np.random.default_rng(cfg.seed + 99 + 1000 * f).choice(len(tr_n), cfg.max_nuisance_segments, replace=False)
        tr_n = [tr_n[i] for i in sorted(sub)]
    return tr_n


def held_out_parts(segs: list, n_traj: int, cfg: ResidualConfig) -> tuple[list[tuple[list, list]], list[np.ndarray]]:
    """[(train_f, held_f)], [units_f] of the held-out test: with ``folds`` = 1 the one seeded split
    (``loop.split_segments``) as a single fold, else the K folds of ``fold_segments``."""
    if cfg.folds == 1:
        from service.residuals.loop import split_segments

        train, held, units = split_segments(segs, n_traj, cfg)
        return [(train, held)], [units]
    return fold_segments(segs, cfg)


def crossfit(inputs: ResidualInputs, cfg: ResidualConfig, model: ObjectModel, names: list[str], nuis_names: list[str],
             stats: dict, segs: list, ev, report) -> ResidualOutputs:
    """The greedy loop of ``loop.run`` over K = ``folds`` folds (module docstring); K = 1 is the one seeded split:
    its single fold's figures are reported as they are (no fold values, no per-fold records, no final refit).
    ``model`` is the input model, ``segs`` every rollout block, ``ev`` the Evaluator."""
    from service.residuals.loop import (
        _acts_on, _carried_keys, _decide, _fit, _fit_nuisance, _refine_joint, accept_best, acts_on, effect_mask, history_entry,
        inadequacy, judged_candidate, later_rules, not_judged, reduce_blocks,
    )

    K = cfg.folds
    kfold = K > 1  # cross-fitted: fold values, per-fold records, final refit on all units
    parts, units = held_out_parts(segs, len(inputs.trajectories), cfg)
    folds = [_Fold(tr, ho, u) for (tr, ho), u in zip(parts, units)]
    input_model = model
    input_effects = dict(model.effects)
    rng = np.random.default_rng(cfg.seed + 1)
    for f, fd in enumerate(folds):
        fd.model, fd.base_effects = input_model, dict(input_effects)
        fd.held_frames0 = ev.frame_split(input_model, input_effects, fd.held)
        fd.nuisance = {}
        if nuis_names:
            report(0.02 + 0.03 * f / K, (f"fold {f + 1}/{K}: " if kfold else "")
                   + "refitting the model's own uncertain parameters (nuisance)")
            tr_n = nuisance_blocks(fd.train, f, cfg)
            fd.tr_n = tr_n
            fd.gap_segs = list(fd.train)
            fix, e0, e1 = _fit_nuisance(nuis_names, input_model, dict(input_effects), ev, tr_n, cfg, fd.gap_segs)
            fd.nuis_fix = dict(fix)
            fd.nuisance = {"train_error_before": e0, "train_error_after": e1, "train_blocks": len(tr_n)}
            if fix:
                fd.model, fix_sim = apply_effects(input_model, fix)
                fd.base_effects = {**input_effects, **fix_sim}
                th_off = float(fix_sim.get("table_offset", 0.0))
                modes = [
                    classify(fd.model, tr, inputs.table_height + th_off, inputs.robot[k] if inputs.robot is not None else None, cfg)
                    for k, tr in enumerate(inputs.trajectories)
                ]
                fd.train = [dataclasses.replace(sg, mode=modes[sg.traj][sg.start:sg.stop]) for sg in fd.train]
                fd.held = [dataclasses.replace(sg, mode=modes[sg.traj][sg.start:sg.stop]) for sg in fd.held]
        fd.cur_frames = ev.frame_split(fd.model, fd.base_effects, fd.held) if fd.nuis_fix else fd.held_frames0

    def corrections_now() -> dict[str, float]:
        """The corrections effects are judged against: one split's own, else the fold mean (sorted keys)."""
        if not kfold:
            return _flat(folds[0].nuis_fix)
        keys = sorted({k for fd in folds for k in _flat(fd.nuis_fix)})
        out = {}
        for k in keys:
            vals = [_flat(fd.nuis_fix)[k] for fd in folds if k in _flat(fd.nuis_fix)]
            out[k] = float(np.mean(vals))
        return out

    def union_all(frames_per_fold) -> np.ndarray:
        return np.concatenate([reduce_blocks(fr) for fr in frames_per_fold])

    base_err = float(union_all([fd.cur_frames for fd in folds]).mean())
    nuisance_report: dict = {"names": nuis_names, **({} if kfold else folds[0].nuisance), "heldout_error_after": base_err,
                             "corrections": corrections_now()}
    if kfold:
        nuisance_report["folds"] = [{**fd.nuisance, "corrections": _flat(fd.nuis_fix)} for fd in folds]
    pinned = [n for fd in folds for n, th in fd.nuis_fix.items() if at_bound(REGISTRY[n], th)]
    if kfold:
        pinned = sorted(set(pinned))
    max_rel = cfg.max_base_error_rel_learned if nuis_names else cfg.max_base_error_rel
    any_fix = any(fd.nuis_fix for fd in folds)
    ref_model = next((fd.model for fd in folds if fd.nuis_fix), input_model)
    why_not = inadequacy(base_err, ref_model, pinned, any_fix, max_rel)
    nuisance_report["model_adequate"] = why_not is None

    final: dict[str, EffectCandidate] = {}
    chosen_rep: dict[str, tuple] = {}
    release_rep: dict[str, dict] = {}  # ``release_value``: per accepted slide effect, its release-block figures
    history: list[dict] = []
    remaining = list(names)
    n_rounds = min(cfg.max_effects, len(names))
    if why_not is not None:
        n_rounds = 0
        final.update(not_judged(names, why_not))
    for rnd in range(n_rounds):
        round_res = []
        cur = [apply_effects(fd.model, fd.chosen) for fd in folds]
        for ci, name in enumerate(remaining):
            report((rnd + ci / max(len(remaining), 1)) / max(n_rounds, 1) * 0.9,
                   f"round {rnd + 1}: fitting {name}" + (f" ({K} folds)" if kfold else ""))
            eff = REGISTRY[name]
            sig = float(eff.signature(stats))
            guess = eff.guess(stats, input_model if kfold else folds[0].model)  # one split: its corrected model
            tr_e, ho_idx = [], []
            for f, fd in enumerate(folds):
                t = [sg for sg in fd.train if _acts_on(sg, eff)]
                if len(t) > cfg.max_train_segments:
                    sub = np.random.default_rng(cfg.seed + 7 * rnd + ci + 1000 * f).choice(len(t), cfg.max_train_segments, replace=False)
                    t = [t[i] for i in sorted(sub)]
                tr_e.append(t)
                ho_idx.append(np.array([i for i, sg in enumerate(fd.held) if _acts_on(sg, eff)], int))
            n_held = sum(len(h) for h in ho_idx)
            if min(len(t) for t in tr_e) < 2 or n_held < 2:
                counts = f"train {[len(t) for t in tr_e]} per fold" if kfold else f"train {len(tr_e[0])}"
                final[name] = EffectCandidate(
                    name, {}, float("nan"), float("nan"), False,
                    f"rejected: too few blocks in its modes {eff.modes} ({counts}, held-out {n_held})",
                    signature=sig, round=rnd, acts_on=acts_on(eff))
                continue
            per = []  # per fold: dict of figures
            for f, fd in enumerate(folds):
                cm, cs = cur[f]
                tr_masks = [effect_mask(sg, eff) for sg in tr_e[f]]
                ho_masks = [effect_mask(fd.held[i], eff) for i in ho_idx[f]]
                train_before = float(ev.errors(cm, {**fd.base_effects, **cs}, tr_e[f], tr_masks).mean())
                theta, e_train = _fit(eff, guess, fd.model, fd.base_effects, fd.chosen, ev, tr_e[f], cfg)
                m_after, s_after = apply_effects(fd.model, {**fd.chosen, name: theta})
                after_frames = ev.frame_split(m_after, {**fd.base_effects, **s_after}, fd.held)
                per.append({"theta": theta, "e_train": e_train, "train_before": train_before, "tr_masks": tr_masks,
                            "ho_masks": ho_masks, "ho_idx": ho_idx[f], "after_frames": after_frames, "nuis": fd.nuis_fix, "refit": False,
                            "after_model": (m_after, {**fd.base_effects, **s_after})})

            def gather():
                rb = np.concatenate([reduce_blocks([fd.cur_frames[i] for i in ho_idx[f]], per[f]["ho_masks"])
                                     for f, fd in enumerate(folds)])
                ra = np.concatenate([reduce_blocks([per[f]["after_frames"][i] for i in ho_idx[f]], per[f]["ho_masks"])
                                     for f in range(K)])
                u = np.concatenate([fd.units[ho_idx[f]] for f, fd in enumerate(folds)])
                ab = union_all([fd.cur_frames for fd in folds])
                aa = union_all([p["after_frames"] for p in per])
                return rb, ra, u, ab, aa

            def gather_acting():
                """Issue #6's error where the effect acts: its component on its frames, per held-out block."""
                return tuple(np.concatenate([reduce_blocks([fr[i] for i in ho_idx[f]], per[f]["ho_masks"], eff.component)
                                             for f, fr in enumerate(frs)])
                             for frs in ([fd.cur_frames for fd in folds], [p["after_frames"] for p in per]))

            rel_before, rel_after, u_all, all_before, all_after = gather()
            ok, why, rel = _decide(rel_before, rel_after, u_all, cfg, rng)
            helps = [p["e_train"] < (1.0 - 0.5 * cfg.min_rel_improvement) * p["train_before"]
                     and not is_negligible(eff, p["theta"], fd.model) for p, fd in zip(per, folds)]
            if any(fd.nuis_fix for fd in folds) and (ok or any(helps)):
                for f, fd in enumerate(folds):
                    if not fd.nuis_fix:
                        continue
                    cand_nuis, theta = _refine_joint(fd.nuis_fix, eff, per[f]["theta"], fd.chosen, input_model,
                                                     dict(input_effects), ev, fd.tr_n, cfg, fd.gap_segs)
                    m_after, s_after = apply_effects(input_model, {**cand_nuis, **fd.chosen, name: theta})
                    per[f]["after_frames"] = ev.frame_split(m_after, {**input_effects, **s_after}, fd.held)
                    per[f]["after_model"] = (m_after, {**input_effects, **s_after})
                    per[f]["e_train"] = float(ev.errors(m_after, {**input_effects, **s_after}, tr_e[f], per[f]["tr_masks"]).mean())
                    per[f].update(theta=theta, nuis=cand_nuis, refit=True)
                rel_before, rel_after, u_all, all_before, all_after = gather()
                ok, why, rel = _decide(rel_before, rel_after, u_all, cfg, rng)
                why = why.replace("held-out error", "(refitted with the corrections) held-out error", 1)
            thetas = np.array([p["theta"] for p in per], float)
            theta_rep = eff.clip(tuple(float(v) for v in thetas.mean(0)))  # one split: its own θ
            if kfold:
                fold_txt = "fold values " + "; ".join("(" + ", ".join(f"{v:.4g}" for v in th) + ")" for th in thetas)
                why = f"{why}; {K} folds, {fold_txt}"
            bound_f = [f + 1 for f, p in enumerate(per) if at_bound(eff, p["theta"])]
            ok, why = later_rules(ok, why, eff, theta_rep, folds[0].model, all_before, all_after,
                                  [fd.held[i] for f, fd in enumerate(folds) for i in ho_idx[f]], rel_before, rel_after,
                                  (f" in fold(s) {bound_f}" if kfold else "") if bound_f else None)
            ok, why = agreement_rule(ok, why, eff, thetas, folds[0].model)  # K >= 2 only
            if cfg.release_blocks is not None and name in SLIDE_EFFECTS:  # rule 10
                ok, why = release_rule(ok, why, eff, per, folds, cur, ev, cfg)
            n_tr = sum(len(t) for t in tr_e)
            act_before, act_after = gather_acting()
            cand = judged_candidate(name, eff, theta_rep, guess, sig, why, rel_before, rel_after, all_before, all_after,
                                    np.mean([p["train_before"] for p in per]), np.mean([p["e_train"] for p in per]),
                                    rnd, {"train": n_tr, "heldout": int(len(rel_before)), **({"folds": K} if kfold else {})},
                                    act_before, act_after)
            per_fold = []
            for f, (p, fd) in enumerate(zip(per, folds)):
                b = reduce_blocks([fd.cur_frames[i] for i in ho_idx[f]], p["ho_masks"])
                a = reduce_blocks([p["after_frames"][i] for i in ho_idx[f]], p["ho_masks"])
                ba = reduce_blocks([fd.cur_frames[i] for i in ho_idx[f]], p["ho_masks"], eff.component)
                aa = reduce_blocks([p["after_frames"][i] for i in ho_idx[f]], p["ho_masks"], eff.component)
                per_fold.append({"params": {k: float(v) for k, v in zip(eff.params, p["theta"])},
                                 "heldout_error_before": float(np.mean(b)) if len(b) else None,
                                 "heldout_error_after": float(np.mean(a)) if len(a) else None,
                                 "heldout_acting_before": float(np.mean(ba)) if len(ba) else None,
                                 "heldout_acting_after": float(np.mean(aa)) if len(aa) else None,
                                 "train_error_before": p["train_before"], "train_error_after": p["e_train"],
                                 "blocks": {"train": len(tr_e[f]), "heldout": int(len(ho_idx[f]))},
                                 "refit_with_corrections": p["refit"]})
            # ranked by the fall of the error over all held-out frames: a common basis for effects that act
            # on different frames (an effect on many frames can otherwise outrank the one that explains them)
            round_res.append((ok, float(all_before.mean() - all_after.mean()), cand, per, theta_rep))
            final[name] = cand
            history.append(history_entry(rnd, cand, ok, **({"folds": per_fold} if kfold else {})))
        if cfg.lookalike_refute:
            round_res = lookalike_refutation(round_res, folds, cfg, final, history, rnd)
        best = accept_best(round_res, final)
        if best is None:
            break
        ok, gain, cand, per, theta_rep = best
        chosen_rep[cand.effect] = theta_rep
        if (cfg.release_value is not None and kfold and cand.effect in SLIDE_EFFECTS
                and cand.effect in cfg.release_value_effects
                and (cfg.release_value_models == "all" or nuis_names)):
            report((rnd + 1) / max(n_rounds, 1) * 0.9, f"{cand.effect}: its value on the folds' release blocks")
            rv = release_value_folds(REGISTRY[cand.effect], per, folds, input_model, input_effects, ev, cfg)
            rv["heldout_acting_before"] = final[cand.effect].heldout_acting_before
            rv["heldout_acting_after_launch"] = final[cand.effect].heldout_acting_after
            release_rep[cand.effect] = rv
        remaining.remove(cand.effect)
        for fd, p in zip(folds, per):
            fd.chosen[cand.effect] = p["theta"]
            fd.cur_frames = p["after_frames"]
            if p["nuis"] is not fd.nuis_fix:  # corrections refitted together with the accepted effect
                fd.nuis_fix = p["nuis"]
                fd.model, fix_sim = apply_effects(input_model, fd.nuis_fix)
                fd.base_effects = {**input_effects, **fix_sim}
        if not remaining:
            break

    refit_report: dict = {}
    if chosen_rep and kfold:  # the decision is the cross-fitted one; the reported value is one more fit on all units
        report(0.9, f"refitting the accepted effects {list(chosen_rep)} on all units")
        refit, refit_report = final_refit(inputs, cfg, input_model, chosen_rep, nuis_names, stats, segs, ev,
                                          {n: r["fold_mean"] for n, r in release_rep.items()})
        for name, theta in refit.items():
            c = final[name]
            extra = {}
            if name in release_rep:  # the after model carries the release value: criterion 3 at the folds' release values
                rv = release_rep[name]
                extra["heldout_acting_after"] = rv["heldout_acting_after"]
                refit_report["effects"].setdefault(name, {})["release_folds"] = [
                    {k: float(v) for k, v in zip(REGISTRY[name].params, th)} for th in rv["folds"]]
                refit_report["effects"][name].update(
                    release_heldout_acting_before=rv["heldout_acting_before"],
                    release_heldout_acting_after=rv["heldout_acting_after"],
                    launch_heldout_acting_after=rv["heldout_acting_after_launch"],
                    release_blocks_folds=rv["release_blocks"], launch_value_kept_folds=rv["launch_value_kept"])
            final[name] = dataclasses.replace(c, params={k: float(v) for k, v in zip(REGISTRY[name].params, theta)},
                                              reason=c.reason + "; " + refit_report["notes"][name], **extra)
        fold_mean = dict(chosen_rep)
        chosen_rep = dict(refit)
        refit_report["fold_mean"] = _flat(fold_mean)
    report(0.92, "errors by mode before/after")
    new_model, _ = apply_effects(input_model, chosen_rep)
    accepted_effects = _flat(chosen_rep)
    out_model, recording = fold_into_model(new_model, accepted_effects, _carried_keys())
    overall_b, table_b = ev.by_mode_groups([(input_model, input_effects, fd.held) for fd in folds])
    if any(fd.nuis_fix for fd in folds):
        overall_c, table_c = ev.by_mode_groups([(fd.model, fd.base_effects, fd.held) for fd in folds])
    else:
        overall_c, table_c = overall_b, table_b
    if chosen_rep:
        groups = []
        for fd in folds:
            m, s = apply_effects(fd.model, fd.chosen)
            groups.append((m, {**fd.base_effects, **s}, fd.held))
        overall_a, table_a = ev.by_mode_groups(groups)
    else:
        overall_a, table_a = overall_c, table_c
    corrections = corrections_now()
    if kfold:  # (one split: by_mode["nuisance"] keeps the corrections the first round was judged against)
        nuisance_report["corrections"] = corrections
    held_before0 = union_all([fd.held_frames0 for fd in folds])
    held_after = union_all([fd.cur_frames for fd in folds])
    by_mode = {
        "residual": stats,
        "rollout_before": table_b,
        "rollout_after": table_a,
        "rollout_corrected": table_c,
        "error_corrected": {**overall_c, "scalar_m": nuisance_report["heldout_error_after"]},
        "nuisance": nuisance_report,
        "segments": {"train_pool": sum(len(fd.train) for fd in folds), "heldout": sum(len(fd.held) for fd in folds),
                     **({"folds": K} if kfold else {})},
    }
    if kfold:
        by_mode["folds"] = [{"train_pool": len(fd.train), "heldout": len(fd.held), "units": int(len(np.unique(fd.units))),
                             "effects": _flat(fd.chosen), "corrections": _flat(fd.nuis_fix),
                             "heldout_error_before": float(reduce_blocks(fd.held_frames0).mean()),
                             "heldout_error_after": float(reduce_blocks(fd.cur_frames).mean())} for fd in folds]
    by_mode.update({"rot_scale_m": ev.rot_scale, "rollouts": ev.calls, "recording_effects": recording, "rounds": history})
    if kfold:
        by_mode["refit"] = refit_report
    ordered = [final[n] for n in names if n in final]
    report(1.0, "done")
    return ResidualOutputs(
        candidates=tuple(ordered),
        accepted=tuple(chosen_rep),
        effects=accepted_effects,
        error_before={**overall_b, "scalar_m": float(held_before0.mean())},
        error_after={**overall_a, "scalar_m": float(held_after.mean())},
        by_mode=by_mode,
        model=out_model,
        series={"heldout_error_before": held_before0, "heldout_error_after": held_after},
        recording_effects=recording,
        corrections=corrections,
    )


def final_refit(inputs: ResidualInputs, cfg: ResidualConfig, input_model: ObjectModel, chosen: dict[str, tuple],
                nuis_names: list[str], stats: dict, segs: list, ev,
                release: dict[str, tuple] | None = None) -> tuple[dict[str, tuple], dict]:
    """The accepted effects' parameters fitted once more on all units (cross-validation decides, a final fit on all
    the data gives the value): the fold values each saw the training blocks of K − 1 folds only, capped at
    ``max_train_segments``; here every unit is in the pool and the cap is K × ``max_train_segments`` (the blocks
    the K fold fits used together), K × ``max_nuisance_segments`` for the corrections.

    The routine of one split: the corrections (if any) fitted from "no change" on all units (``_fit_nuisance``; here
    with the accepted effects in place at their fold means) and the contact modes re-classified with them; then each accepted effect, in the order of acceptance, fitted by
    ``_fit`` (guess: its fold mean) on its own frames of the blocks where it acts, on top of the other accepted
    effects (already refitted ones at their new value, the others at their fold mean: one Gauss–Seidel sweep, so
    the values are fitted jointly) and refitted jointly with the corrections (``_refine_joint``) when there are
    corrections. Returns ({name: θ} in the order of ``chosen``, report).

    ``release`` (``ResidualConfig.release_value``): the accepted slide effects whose reported value is then fitted on
    the release blocks of all units instead (``fit_on_release``, guess: the folds' release-value mean), after the
    sweep above, on its corrections and the other effects at their refitted values (the corrections are not refitted:
    what the struck size does is in the release blocks' start states); the launch-block refit is kept in the report
    (``effects[name]["launch_params"]``)."""
    from service.residuals.loop import _acts_on, _fit, _fit_nuisance, _refine_joint

    K = cfg.folds
    input_effects = dict(input_model.effects)
    model, base_effects = input_model, dict(input_effects)
    pool = list(segs)
    rng = np.random.default_rng(cfg.seed + 4242)
    rep: dict = {"train_cap": K * cfg.max_train_segments, "effects": {}, "notes": {}, "corrections": {}}
    nuis_fix: dict[str, tuple] = {}
    tr_n: list = []
    if nuis_names:
        tr_n = list(pool)
        cap = K * cfg.max_nuisance_segments
        if len(tr_n) > cap:
            tr_n = [tr_n[i] for i in sorted(rng.choice(len(tr_n), cap, replace=False))]
        # fitted with the accepted effects in place (at their fold means), so that the corrections do not soak up
        # the effects first (the single split fits them before any effect is known)
        m_eff, s_eff = apply_effects(input_model, chosen)
        gap_segs = list(pool)  # every block, with the input model's modes (the contact-gap term's strikes)
        fix, e0, e1 = _fit_nuisance(nuis_names, m_eff, {**input_effects, **s_eff}, ev, tr_n, cfg, gap_segs)
        nuis_fix = dict(fix)
        rep["nuisance"] = {"train_error_before": e0, "train_error_after": e1, "train_blocks": len(tr_n)}
        if fix:
            model, fix_sim = apply_effects(input_model, fix)
            base_effects = {**input_effects, **fix_sim}
            th_off = float(fix_sim.get("table_offset", 0.0))
            modes = [
                classify(model, tr, inputs.table_height + th_off, inputs.robot[k] if inputs.robot is not None else None, cfg)
                for k, tr in enumerate(inputs.trajectories)
            ]
            pool = [dataclasses.replace(sg, mode=modes[sg.traj][sg.start:sg.stop]) for sg in pool]
    refit: dict[str, tuple] = {}
    for i, (name, theta_mean) in enumerate(chosen.items()):
        eff = REGISTRY[name]
        others = {n: refit.get(n, th) for n, th in chosen.items() if n != name}
        tr = [sg for sg in pool if _acts_on(sg, eff)]
        if len(tr) > K * cfg.max_train_segments:
            sub = np.random.default_rng(cfg.seed + 4243 + i).choice(len(tr), K * cfg.max_train_segments, replace=False)
            tr = [tr[j] for j in sorted(sub)]
        if len(tr) < 2:  # cannot happen with the blocks the folds had (all units are in the pool); kept safe
            refit[name] = tuple(theta_mean)
            rep["notes"][name] = f"fold mean kept: {len(tr)} training block(s) on all units"
            continue
        theta, e_train = _fit(eff, theta_mean, model, base_effects, others, ev, tr, cfg)
        if nuis_fix:
            nuis_fix, theta = _refine_joint(nuis_fix, eff, theta, others, input_model, dict(input_effects), ev, tr_n, cfg,
                                            gap_segs)
            model, fix_sim = apply_effects(input_model, nuis_fix)
            base_effects = {**input_effects, **fix_sim}
        refit[name] = eff.clip(theta)
        txt = "(" + ", ".join(f"{v:.4g}" for v in refit[name]) + ")"
        flags = [w for w, bad in (("on its bound", at_bound(eff, refit[name])),
                                  ("within its resolution of no effect", is_negligible(eff, refit[name], model))) if bad]
        rep["notes"][name] = (f"value refitted on all units {txt} ({len(tr)} training blocks; the decision is the "
                              f"cross-fitted one, fold mean (" + ", ".join(f"{v:.4g}" for v in theta_mean) + ")"
                              + (f"; the refit is {' and '.join(flags)}" if flags else "") + ")")
        rep["effects"][name] = {"params": {k: float(v) for k, v in zip(eff.params, refit[name])},
                                "fold_mean": {k: float(v) for k, v in zip(eff.params, theta_mean)},
                                "train_blocks": len(tr), "train_error_fit": float(e_train)}
    for name, guess in (release or {}).items():
        eff = REGISTRY[name]
        others = {n: th for n, th in refit.items() if n != name}
        launch = refit[name]
        theta, n_rel = fit_on_release(eff, guess, model, base_effects, others, ev, pool, cfg.release_value, cfg,
                                      K * cfg.max_train_segments)
        if theta is None:
            rep["notes"][name] += f"; release blocks: {n_rel}, the launch-block refit kept"
        else:
            refit[name] = theta
            rep["notes"][name] += ("; value fitted on the release blocks of all units (" + ", ".join(f"{v:.4g}" for v in theta)
                                   + f", {n_rel} blocks; folds' release values mean ("
                                   + ", ".join(f"{v:.4g}" for v in guess) + "))")
        rep["effects"].setdefault(name, {}).update(params={k: float(v) for k, v in zip(eff.params, refit[name])},
                                    launch_params={k: float(v) for k, v in zip(eff.params, launch)},
                                    release_fold_mean={k: float(v) for k, v in zip(eff.params, guess)},
                                    release_blocks=n_rel)
    rep["corrections"] = _flat(nuis_fix)
    return {n: refit[n] for n in chosen}, rep

