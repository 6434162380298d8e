"""K-fold cross-fitting of the held-out test (ResidualConfig.folds, docs/residuals.md §4): every unit held out
exactly once, fits never see the units they are judged on, and the rules applied to the union of the folds.

Tosses in free flight far above the table with a closed-form simulator (semi-implicit Euler under gravity, no
rotation, substeps of <= 2 ms as the built-in simulator), so the loop runs in milliseconds: one 0.15 s block per toss."""

import dataclasses

import numpy as np

from service.residuals import run
from service.residuals.crossfit import fold_segments
from service.residuals.loop import Segment
from service.residuals.types import ObservedTrajectory, ResidualConfig, ResidualInputs
from service.transforms import make_X, so3_exp
from tests.residuals.lab import cube_model

H = 1.0 / 148.0


def _steps(p, v, g, dt, max_h=0.002):
    """Semi-implicit Euler over dt in substeps of <= max_h (the built-in simulator's ``sim_substep_s``)."""
    n = int(np.ceil(dt / max_h - 1e-9))
    for _ in range(n):
        v = v + g * (dt / n)
        p = p + v * (dt / n)
    return p, v


def _ballistic(req):
    """Free flight under the scaled gravity at the output times; the orientation stays X_WO0's."""
    g = np.array([0.0, 0.0, -9.81 * float(req.effects.get("gravity_scale", 1.0))])
    X = np.repeat(np.asarray(req.X_WO0, float)[None], len(req.t), 0)
    p, v = req.X_WO0[:3, 3].astype(float).copy(), np.asarray(req.v0_WO_W, float).copy()
    for k in range(1, len(req.t)):
        p, v = _steps(p, v, g, req.t[k] - req.t[k - 1])
        X[k, :3, 3] = p
    return X


def _tosses(n, g_scale, seed, frames=30, noise_m=1.5e-4, spin=0.0):
    """Free-flight tosses under gravity g_scale·g with position noise; ``spin`` (rad/s) > 0: the observed orientation
    turns at that rate about z, which the closed-form simulator does not reproduce (a rotation error that no gravity
    can change)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        p = np.array([0.0, 0.0, 1.0]) + rng.normal(0, 0.1, 3)
        v = rng.normal(0, 0.5, 3) + [0.0, 0.0, 1.0]
        P = []
        for _k in range(frames):
            P.append(p.copy())
            p, v = _steps(p, v, np.array([0.0, 0.0, -9.81 * g_scale]), H)
        X = np.stack([make_X(np.eye(3) if spin == 0.0 else so3_exp(np.array([0.0, 0.0, spin * k * H])),
                             q + rng.normal(0, noise_m, 3)) for k, q in enumerate(P)])
        out.append(ObservedTrajectory(t=np.arange(frames) * H, X_WO=X))
    return tuple(out)


CFG = dataclasses.replace(ResidualConfig.fast(), candidates=("gravity_scale",), max_effects=1, fit_maxiter=24)


def _run(trajs, folds, seed=0):
    inputs = ResidualInputs(cube_model(), trajs, -10.0, simulate=_ballistic)
    return run(inputs, dataclasses.replace(CFG, folds=folds, seed=seed))


def test_every_unit_is_held_out_exactly_once_and_never_trained_on():
    segs = [Segment(traj, 5 * b, 5 * b + 5, np.zeros(5), np.zeros((5, 4, 4)), np.ones(5, bool), np.zeros(5, int),
                    np.eye(4), np.zeros(3), np.zeros(3), None) for traj in range(7) for b in range(3)]
    for cfg, key in ((ResidualConfig(folds=2, seed=3), lambda s: s.traj),  # >= 4 trajectories: tosses are the units
                     (ResidualConfig(folds=3, seed=3), lambda s: s.traj)):
        parts, units = fold_segments(segs, cfg)
        assert len(parts) == cfg.folds
        held = [key(s) for _, ho in parts for s in ho]
        assert sorted(held) == sorted(key(s) for s in segs)  # every block held out once
        assert sorted(set(np.concatenate(units))) == list(range(7))
        for (train, ho), u in zip(parts, units):
            assert not {s.traj for s in train} & {s.traj for s in ho}  # the fits never see a held-out toss
            assert len(train) + len(ho) == len(segs) and list(u) == [s.traj for s in ho]
    one = [s for s in segs if s.traj == 0]  # one session: its time blocks are the units
    parts, units = fold_segments(one, ResidualConfig(folds=2))
    assert sorted(np.concatenate(units)) == [0, 1, 2] and sum(len(ho) for _, ho in parts) == 3


def test_two_folds_confirm_what_one_split_cannot():
    # 6 tosses, one block each, gravity 10 % low: one split holds out 3 blocks, where the sign test cannot reach
    # p < 0.05 (p >= 1/8) however clear the effect; with 2 folds all 6 are held out once (p = 1/64)
    trajs = _tosses(6, 0.9, seed=1)
    one = _run(trajs, 1)
    assert one.accepted == ()
    assert "not consistent across blocks" in one.candidates[0].reason
    two = _run(trajs, 2)
    assert two.accepted == ("gravity_scale",), two.candidates[0].reason
    assert abs(two.effects["gravity_scale"] - 0.9) < 0.01
    assert two.model is not None and two.by_mode["segments"]["heldout"] == 6
    folds = two.by_mode["folds"]
    assert [f["units"] for f in folds] == [3, 3]
    per = two.by_mode["rounds"][0]["folds"]  # each fold fitted on the other's tosses
    assert len(per) == 2 and all(abs(p["params"]["gravity_scale"] - 0.9) < 0.01 for p in per)
    assert [p["blocks"] for p in per] == [{"train": 3, "heldout": 3}] * 2  # fitted on the other fold's 3 tosses
    # the value reported is one more fit on all 6 tosses (the decision stays the cross-fitted one); the fold mean
    # is reported beside it
    refit = two.by_mode["refit"]["effects"]["gravity_scale"]
    assert refit["train_blocks"] == 6 and np.isclose(two.effects["gravity_scale"], refit["params"]["gravity_scale"])
    assert np.isclose(refit["fold_mean"]["gravity_scale"], np.mean([p["params"]["gravity_scale"] for p in per]))
    assert two.candidates[0].params == refit["params"] and "refitted on all units" in two.candidates[0].reason
    assert two.error_after["scalar_m"] < 0.3 * two.error_before["scalar_m"]


def test_noise_is_not_accepted_with_two_folds():
    # no hidden effect, 12 tosses with tracking noise: gravity is fitted on each fold's complement and judged on
    # its held-out tosses; accepted in at most about α of the draws
    acc = [bool(_run(_tosses(12, 1.0, seed=100 + k, noise_m=1e-3), 2, seed=k).accepted) for k in range(20)]
    assert sum(acc) <= 1
