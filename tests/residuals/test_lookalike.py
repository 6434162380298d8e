"""Rule 9 (docs/residuals.md §4, ``ResidualConfig.lookalike_check``): of two look-alike effects (table friction and
linear damping both decelerate a slide), a passing candidate is accepted only if its held-out predictions beat the
other's, fitted in the same round, on the blocks where either acts."""

import numpy as np
import pytest

from service.residuals.crossfit import _Fold, lookalike_rule
from service.residuals.effects import REGISTRY
from service.residuals.loop import Segment, head_to_head
from service.residuals.modes import FREE, SLIDING
from service.residuals.types import EffectCandidate, ResidualConfig


def _blocks(n: int, mode: int, frames: int = 8) -> list[Segment]:
    t = np.arange(frames) / 30.0
    return [Segment(k, 0, frames, t, np.tile(np.eye(4), (frames, 1, 1)), np.ones(frames, bool),
                    np.full(frames, mode), np.eye(4), np.zeros(3), np.zeros(3), None) for k in range(n)]


def _entry(name: str, ok: bool, fold_errs: list[np.ndarray], frames: int = 8) -> tuple:
    """A round result (passes, all-frame fall, candidate, per-fold figures, θ̄) with per-block errors (m) held out."""
    eff = REGISTRY[name]
    cand = EffectCandidate(name, {eff.params[0]: 0.2}, 0.01, 0.007, False,
                           "passes; held-out error +30%" if ok else "rejected: fitted value on its bound", round=0)
    per = [{"after_frames": [np.full(frames, e) for e in errs]} for errs in fold_errs]
    return (ok, 1e-3, cand, per, (0.2,))


def _round(err_fric, err_damp, fric_ok=True, damp_ok=False, n=12, seed=0):
    """Two folds of n sliding blocks each; each candidate's held-out block errors = its level × (1 ± 10 % noise)."""
    rng = np.random.default_rng(seed)
    folds = [_Fold(train=[], held=_blocks(n, SLIDING), units=np.arange(n) + f * n) for f in range(2)]
    noise = [1 + 0.1 * rng.standard_normal(n) for _ in range(2)]
    fric = _entry("friction_table", fric_ok, [err_fric * z for z in noise])
    damp = _entry("linear_damping", damp_ok, [err_damp * z * (1 + 0.02 * rng.standard_normal(n)) for z in noise])
    return [fric, damp], folds


def _apply(round_res, folds):
    final = {r[2].effect: r[2] for r in round_res}
    history = [{"round": 1, "effect": r[2].effect, "passes": r[0], "reason": r[2].reason} for r in round_res]
    out = lookalike_rule(round_res, folds, ResidualConfig(lookalike_check=True), final, history, 0)
    return {r[2].effect: r for r in out}, final, history


def test_passing_friction_rejected_when_the_damping_predicts_better():
    # the wrong friction passes on its own; the damping (failing an earlier rule) predicts the slides 25 % better
    res, final, history = _apply(*_round(err_fric=0.008, err_damp=0.006))
    assert not res["friction_table"][0]
    assert final["friction_table"].reason.startswith("rejected: does not predict the held-out blocks better than its "
                                                     "look-alike linear_damping")
    assert "fitted value on its bound" not in final["friction_table"].reason
    assert next(h for h in history if h["effect"] == "friction_table")["passes"] is False
    assert not res["linear_damping"][0]  # the rule never makes a failing candidate pass


def test_both_passing_the_better_one_stays():
    res, final, _ = _apply(*_round(err_fric=0.008, err_damp=0.005, damp_ok=True))
    assert res["linear_damping"][0] and not res["friction_table"][0]
    assert "beats its look-alike friction_table" in final["linear_damping"].reason
    res, _, _ = _apply(*_round(err_fric=0.005, err_damp=0.008, damp_ok=True))
    assert res["friction_table"][0] and not res["linear_damping"][0]


def test_equal_predictions_neither_accepted():
    # the same predictions up to 2 % noise: the data do not say which, so neither is accepted
    res, _, _ = _apply(*_round(err_fric=0.006, err_damp=0.006, damp_ok=True))
    assert not res["friction_table"][0] and not res["linear_damping"][0]


def test_without_the_lookalike_or_outside_the_pair_nothing_changes():
    round_res, folds = _round(err_fric=0.008, err_damp=0.006)
    res, _, _ = _apply(round_res[:1], folds)  # the damping was not fitted this round
    assert res["friction_table"][0]
    tilt = _entry("table_tilt", True, [np.full(12, 0.009)] * 2)
    res, _, _ = _apply([tilt, round_res[1]], folds)  # a tilt has no look-alike
    assert res["table_tilt"][0]


def test_only_blocks_where_either_acts_are_compared():
    # blocks of free flight count for the damping (it acts there), resting ones for neither
    folds = [_Fold(train=[], held=_blocks(6, SLIDING) + _blocks(6, FREE), units=np.arange(12) + 12 * f) for f in range(2)]
    fric = _entry("friction_table", True, [np.r_[np.full(6, 0.005), np.full(6, 0.009)]] * 2)
    damp = _entry("linear_damping", True, [np.r_[np.full(6, 0.005), np.full(6, 0.004)]] * 2)
    res, final, _ = _apply([fric, damp], folds)
    assert res["linear_damping"][0] and not res["friction_table"][0]
    assert "on 24 blocks" in final["linear_damping"].reason


def test_head_to_head_statistic():
    cfg = ResidualConfig()
    rng = np.random.default_rng(1)
    b = 0.006 * (1 + 0.1 * rng.standard_normal(20))
    better, txt = head_to_head(b, 0.8 * b, np.arange(20), cfg, rng)
    assert better and "20/0 blocks" in txt
    assert not head_to_head(b, b * (1 + 0.01 * rng.standard_normal(20)), np.arange(20), cfg, rng)[0]
    assert not head_to_head(b, 1.2 * b, np.arange(20), cfg, rng)[0]


def test_config_flag_validated():
    assert ResidualConfig().lookalike_check is False
    with pytest.raises(ValueError):
        ResidualConfig(lookalike_check="yes")
