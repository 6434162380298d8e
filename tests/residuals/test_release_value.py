"""The reported value of an accepted slide effect fitted on the slide alone (``ResidualConfig.release_value``,
docs/residuals.md §4 "Reported value"): the final refit's value and the held-out error where the effect acts at each
fold's value fitted on its training release blocks (``crossfit.fit_on_release``, ``release_value_folds``,
``final_refit``). On by default for learned models' linear damping; the decision is not changed."""

import dataclasses

import numpy as np
import pytest

from service.residuals.crossfit import _Fold, final_refit, fit_on_release, release_value_folds
from service.residuals.effects import REGISTRY
from service.residuals.loop import effect_mask
from service.residuals.types import ResidualConfig
from tests.residuals.test_nuisance_restart import _model
from tests.residuals.test_release_blocks import _launch_block

B_SLIDE, B_LAUNCH = 2.0, 3.5  # 1/s: the damping the slide alone shows, the one the whole launch block takes


class _SlideEvaluator:
    """A block's error is |b − B_SLIDE| on a release block (rolled out without the sphere) and |b − B_LAUNCH| on a
    launch block (the struck size's look-alike), + 1 mm; per frame, all of it in the position."""

    def _err(self, effects, seg):
        b = float(effects.get("linear_damping", 0.0))
        return 1e-3 + 1e-3 * abs(b - (B_SLIDE if seg.robot is None else B_LAUNCH))

    def errors(self, model, effects, segs, masks=None):
        return np.array([self._err(effects, s) for s in segs])

    def frame_split(self, model, effects, segs):
        return [np.column_stack([np.full(len(s.t), self._err(effects, s)), np.zeros(len(s.t))]) for s in segs]


CFG = ResidualConfig(release_value=1, fit_maxiter=24)
EFF = REGISTRY["linear_damping"]


def test_config_release_value():
    cfg = ResidualConfig()  # on by default, as judged: gap 1, the cubic start, learned models, the linear damping
    assert (cfg.release_value, cfg.release_value_degree, cfg.release_value_models, cfg.release_value_effects) == (
        1, 3, "learned", ("linear_damping",))
    assert ResidualConfig(release_value=None).release_value is None
    assert ResidualConfig(release_value=2).release_value == 2
    for v in (0, -1, 1.5, True, "1"):
        with pytest.raises(ValueError, match="release_value"):
            ResidualConfig(release_value=v)
    assert ResidualConfig(folds=1).release_value == 1  # one split: no final refit, nothing to do


def test_fit_on_release_takes_the_slide_value_not_the_launch_value():
    launches = [_launch_block() for _ in range(4)]
    theta, n = fit_on_release(EFF, (B_LAUNCH,), _model(), {}, {}, _SlideEvaluator(), launches, 1, CFG, 10)
    assert n == 4 and theta[0] == pytest.approx(B_SLIDE, abs=0.01)
    theta, n = fit_on_release(EFF, (B_LAUNCH,), _model(), {}, {}, _SlideEvaluator(), launches, 1, CFG, 3)
    assert n == 3 and theta[0] == pytest.approx(B_SLIDE, abs=0.01)  # capped
    # no release block (not launch blocks, or one only): no value
    plain = [dataclasses.replace(s, launch=False) for s in launches]
    assert fit_on_release(EFF, (B_LAUNCH,), _model(), {}, {}, _SlideEvaluator(), plain, 1, CFG, 10) == (None, 0)
    assert fit_on_release(EFF, (B_LAUNCH,), _model(), {}, {}, _SlideEvaluator(), launches[:1], 1, CFG, 10)[0] is None


def _per_fold(held, theta):
    idx = np.arange(len(held))
    return {"theta": (theta,), "nuis": {}, "ho_idx": idx, "ho_masks": [effect_mask(held[i], EFF) for i in idx]}


def test_release_value_folds_fits_each_fold_and_measures_where_it_acts():
    model = _model()
    folds = []
    for n_train in (4, 1):  # the second fold has one training release block only: its launch value is kept
        fd = _Fold([_launch_block() for _ in range(n_train)], [_launch_block() for _ in range(3)], np.arange(3))
        fd.model, fd.base_effects = model, {}
        folds.append(fd)
    per = [_per_fold(fd.held, B_LAUNCH) for fd in folds]
    rv = release_value_folds(EFF, per, folds, model, {}, _SlideEvaluator(), CFG)
    assert rv["folds"][0][0] == pytest.approx(B_SLIDE, abs=0.01) and rv["folds"][1] == (B_LAUNCH,)
    assert rv["release_blocks"] == [4, 1] and rv["launch_value_kept"] == [2]
    assert rv["fold_mean"][0] == pytest.approx(0.5 * (B_SLIDE + B_LAUNCH), abs=0.01)
    # held-out launch blocks (the effect's frames): at B_SLIDE on fold 1 1 mm + 1.5 mm, at B_LAUNCH on fold 2 1 mm
    assert rv["heldout_acting_after"] == pytest.approx(1e-3 + 0.5 * 1.5e-3, rel=0.02)


def test_final_refit_reports_the_release_value_and_keeps_the_launch_refit():
    model = _model()
    segs = [_launch_block() for _ in range(6)]
    cfg = dataclasses.replace(CFG, folds=2)
    chosen = {"linear_damping": (3.0,)}
    off, rep_off = final_refit(None, cfg, model, chosen, [], {}, segs, _SlideEvaluator())
    assert off["linear_damping"][0] == pytest.approx(B_LAUNCH, abs=0.01)
    assert "launch_params" not in rep_off["effects"]["linear_damping"]
    on, rep = final_refit(None, cfg, model, chosen, [], {}, segs, _SlideEvaluator(), {"linear_damping": (2.2,)})
    assert on["linear_damping"][0] == pytest.approx(B_SLIDE, abs=0.01)
    e = rep["effects"]["linear_damping"]
    assert e["launch_params"]["linear_damping"] == pytest.approx(B_LAUNCH, abs=0.01)
    assert e["params"]["linear_damping"] == pytest.approx(B_SLIDE, abs=0.01) and e["release_blocks"] == 6
    assert "release blocks of all units" in rep["notes"]["linear_damping"]


def test_config_release_value_models():
    assert ResidualConfig(release_value_models="learned").release_value_models == "learned"
    for v in ("none", True, None):
        with pytest.raises(ValueError, match="release_value_models"):
            ResidualConfig(release_value_models=v)
    assert ResidualConfig(release_value_effects=("linear_damping",)).release_value_effects == ("linear_damping",)
    for v in (("restitution",), ["linear_damping"], "linear_damping"):
        with pytest.raises(ValueError, match="release_value_effects"):
            ResidualConfig(release_value_effects=v)
    for v in (1, 4, True):
        with pytest.raises(ValueError, match="release_value_degree"):
            ResidualConfig(release_value_degree=v)


def test_cubic_start_state_is_not_biased_by_the_jerk_of_a_damped_slide():
    from service.residuals.loop import start_state
    from service.transforms import make_X

    t = np.arange(9) / 30.0
    v0, a0, j = 0.3, -2.1, 4.0  # a damped slide: its deceleration falls as it slows (positive jerk)
    x = v0 * t + 0.5 * a0 * t**2 + j / 6.0 * t**3
    X = np.array([make_X(np.eye(3), np.array([xi, 0.0, 0.05])) for xi in x])
    h = 1.0 / 30.0 / 17
    _, v2, _ = start_state(t, X, 0, h)
    _, v3, _ = start_state(t, X, 0, h, degree=3)
    assert v2[0] < v0 - 0.02  # the quadratic's one-sided velocity is ≈ 9 % low
    assert v3[0] == pytest.approx(v0 - 0.5 * h * a0 + 0.125 * h * h * j, abs=1e-6)  # the cubic's derivative at −h/2
    X4 = X[:5]  # fewer than 6 frames: the quadratic
    assert np.allclose(start_state(t[:5], X4, 0, h, degree=3)[1], start_state(t[:5], X4, 0, h)[1])
