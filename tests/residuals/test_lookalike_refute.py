"""Rule 9b (docs/residuals.md §4, ``ResidualConfig.lookalike_refute``): a candidate that passes the earlier rules is
rejected when a look-alike fitted in the same round predicts the held-out blocks' position better beyond noise
(the component both the table friction and the linear damping act on); when neither is better nothing changes."""

import numpy as np
import pytest

from service.residuals.crossfit import _Fold, lookalike_refutation, shared_component
from service.residuals.effects import REGISTRY
from service.residuals.loop import Segment, head_to_head
from service.residuals.modes import FREE, SLIDING
from service.residuals.types import EffectCandidate, ResidualConfig

FRAMES = 8


def _blocks(n: int, mode: int) -> list[Segment]:
    t = np.arange(FRAMES) / 30.0
    return [Segment(k, 0, FRAMES, t, np.tile(np.eye(4), (FRAMES, 1, 1)), np.ones(FRAMES, bool),
                    np.full(FRAMES, mode), np.eye(4), np.zeros(3), np.zeros(3), None) for k in range(n)]


def _entry(name: str, ok: bool, pos: list[np.ndarray], rot: list[np.ndarray]) -> tuple:
    """A round result (passes, all-frame fall, candidate, per-fold figures, θ̄) whose held-out blocks carry per-frame
    errors [|Δp|, ρ·∠] (m), constant over each block's frames."""
    eff = REGISTRY[name]
    cand = EffectCandidate(name, {eff.params[0]: 0.2}, 0.01, 0.007, False,
                           "passes; held-out error +30%" if ok else "rejected: improvement not consistent", round=0)
    per = [{"after_frames": [np.tile([p, r], (FRAMES, 1)) for p, r in zip(pf, rf)]} for pf, rf in zip(pos, rot)]
    return (ok, 1e-3, cand, per, (0.2,))


def _round(fric_pos, fric_rot, damp_pos, damp_rot, fric_ok=True, damp_ok=True, n=12, seed=0):
    """Two folds of n sliding blocks; each level × (1 ± 10 % noise shared by both effects, ± 2 % of their own)."""
    rng = np.random.default_rng(seed)
    folds = [_Fold(train=[], held=_blocks(n, SLIDING), units=np.arange(n) + f * n) for f in range(2)]
    z = [1 + 0.1 * rng.standard_normal(n) for _ in range(2)]
    own = lambda: [1 + 0.02 * rng.standard_normal(n) for _ in range(2)]  # noqa: E731
    zf, zd = own(), own()
    fric = _entry("friction_table", fric_ok, [fric_pos * a * b for a, b in zip(z, zf)], [fric_rot * a for a in z])
    damp = _entry("linear_damping", damp_ok, [damp_pos * a * b for a, b in zip(z, zd)], [damp_rot * a for a in z])
    return [fric, damp], folds


def _apply(round_res, folds):
    final = {r[2].effect: r[2] for r in round_res}
    history = [{"round": 1, "effect": r[2].effect, "passes": r[0], "reason": r[2].reason} for r in round_res]
    out = lookalike_refutation(round_res, folds, ResidualConfig(lookalike_refute=True), final, history, 0)
    return {r[2].effect: r for r in out}, final, history


def test_shared_component():
    fric, damp = REGISTRY["friction_table"], REGISTRY["linear_damping"]
    assert shared_component(fric, damp) == "position" == shared_component(damp, fric)
    assert shared_component(fric, fric) == "both"
    assert shared_component(damp, REGISTRY["angular_damping"]) == "both"  # position against rotation: nothing shared


def test_friction_refuted_on_position_even_when_its_rotation_is_better():
    # a hidden damping: the damping's path is 25 % better, the friction's rotation 20 % better; on the scalar error
    # (1.2 + 2.0 against 1.6 + 1.6 mm) the two would tie
    res, final, history = _apply(*_round(fric_pos=0.0016, fric_rot=0.0016, damp_pos=0.0012, damp_rot=0.0020))
    assert not res["friction_table"][0]
    assert final["friction_table"].reason.startswith("rejected: its look-alike linear_damping predicts the held-out "
                                                     "blocks better (position error")
    assert next(h for h in history if h["effect"] == "friction_table")["passes"] is False
    assert res["linear_damping"][0]  # the damping's position is better: it is not refuted
    assert "not refuted by its look-alike friction_table (position error" in final["linear_damping"].reason


def test_rotation_alone_refutes_nothing():
    # the same paths, the damping's rotation much worse: neither is refuted (the greedy pick decides)
    res, final, _ = _apply(*_round(fric_pos=0.0015, fric_rot=0.0012, damp_pos=0.0015, damp_rot=0.0030))
    assert res["friction_table"][0] and res["linear_damping"][0]
    assert "not refuted" in final["friction_table"].reason


def test_a_failing_lookalike_refutes_but_is_never_made_to_pass():
    res, _, _ = _apply(*_round(fric_pos=0.0016, fric_rot=0.0015, damp_pos=0.0011, damp_rot=0.0015, damp_ok=False))
    assert not res["friction_table"][0] and not res["linear_damping"][0]


def test_damping_refuted_when_the_friction_path_is_better():
    res, _, _ = _apply(*_round(fric_pos=0.0011, fric_rot=0.0013, damp_pos=0.0015, damp_rot=0.0013))
    assert res["friction_table"][0] and not res["linear_damping"][0]


def test_blocks_where_neither_acts_are_left_out():
    # resting-only blocks (neither acts) where the damping would be far better: not compared
    folds = [_Fold(train=[], held=_blocks(6, SLIDING) + _blocks(6, 4), units=np.arange(12) + 12 * f) for f in range(2)]
    fric = _entry("friction_table", True, [np.r_[np.full(6, 0.0015), np.full(6, 0.009)]] * 2, [np.full(12, 1e-3)] * 2)
    damp = _entry("linear_damping", True, [np.r_[np.full(6, 0.0015), np.full(6, 0.001)]] * 2, [np.full(12, 1e-3)] * 2)
    res, final, _ = _apply([fric, damp], folds)
    assert res["friction_table"][0] and "on 12 blocks" in final["friction_table"].reason
    # free flight counts (the damping acts there)
    folds = [_Fold(train=[], held=_blocks(6, SLIDING) + _blocks(6, FREE), units=np.arange(12) + 12 * f) for f in range(2)]
    res, final, _ = _apply([fric, damp], folds)
    assert not res["friction_table"][0] and "on 24 blocks" in final["friction_table"].reason


def test_config_flag_validated():
    assert isinstance(ResidualConfig().lookalike_refute, bool)
    with pytest.raises(ValueError):
        ResidualConfig(lookalike_refute="yes")


def test_head_to_head_statistic():
    cfg = ResidualConfig()
    rng = np.random.default_rng(1)
    b = 0.006 * (1 + 0.1 * rng.standard_normal(20))
    better, txt = head_to_head(b, 0.8 * b, np.arange(20), cfg, rng)
    assert better and "20/0 blocks" in txt
    assert not head_to_head(b, b * (1 + 0.01 * rng.standard_normal(20)), np.arange(20), cfg, rng)[0]
    assert not head_to_head(b, 1.2 * b, np.arange(20), cfg, rng)[0]
