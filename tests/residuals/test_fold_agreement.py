"""Rule 8 of cross-fitting (docs/residuals.md §4): an effect that passes rules 1–7 is accepted only if every fold's
fitted value departs from "no effect" the same way (scalars: same sign; vectors: pairwise angle < 90°)."""

import numpy as np

from service.residuals.crossfit import agreement_rule, fold_agreement
from service.residuals.effects import REGISTRY
from tests.residuals.lab import cube_model


def _model(mu_table=0.15):
    m = cube_model(friction=(mu_table, 0.15))
    assert m.friction.object_table == mu_table
    return m


def _tilt(angle_deg, r=0.02):
    a = np.radians(angle_deg)
    return (r * np.cos(a), r * np.sin(a))


def test_vectors_reject_folds_pointing_apart_keep_close_ones():
    tilt, m = REGISTRY["table_tilt"], _model()
    # the two fold values of the wrong tilt on learned-model strike seed 602 (mrad), 109° apart
    ok, txt = fold_agreement(tilt, [(-0.005438, 0.007031), (0.008944, 0.002984)], m)
    assert not ok and "109.3° (>= 90°)" in txt
    assert not fold_agreement(tilt, [_tilt(0), _tilt(95)], m)[0]
    assert not fold_agreement(tilt, [_tilt(10), _tilt(190, 0.004)], m)[0]
    assert fold_agreement(tilt, [_tilt(0), _tilt(60, 0.01)], m)[0]
    assert fold_agreement(tilt, [(0.049, -0.004), (0.051, 0.003)], m)[0]
    # three folds: one pair apart is enough to reject
    assert not fold_agreement(tilt, [_tilt(0), _tilt(60), _tilt(120)], m)[0]
    assert fold_agreement(tilt, [_tilt(0), _tilt(40), _tilt(80)], m)[0]
    # a fold exactly on "no effect" has no direction: no agreement
    assert not fold_agreement(tilt, [_tilt(0), (0.0, 0.0)], m)[0]
    com = REGISTRY["com_offset"]
    assert fold_agreement(com, [(0.012, -0.010, 0.0), (0.010, -0.011, -0.002)], m)[0]
    assert not fold_agreement(com, [(0.012, -0.010, 0.0), (-0.011, 0.008, 0.001)], m)[0]


def test_scalars_same_sign_of_departure_from_null():
    g, m = REGISTRY["gravity_scale"], _model()
    assert fold_agreement(g, [(0.946,), (0.952,)], m)[0]
    assert not fold_agreement(g, [(0.96,), (1.02,)], m)[0]
    # table friction: "no effect" is the model's own friction (0.15 here)
    f = REGISTRY["friction_table"]
    assert fold_agreement(f, [(0.4076,), (0.2714,)], m)[0]
    assert not fold_agreement(f, [(0.30,), (0.10,)], m)[0]
    assert fold_agreement(f, [(0.30,), (0.10,)], _model(0.35))[0]  # both below a prior of 0.35
    assert not fold_agreement(f, [(0.30,), (0.15,)], m)[0]  # one fold on the null value


def test_rule_rejects_only_passing_effects_and_reports_its_figures():
    tilt, m = REGISTRY["table_tilt"], _model()
    ok, why = agreement_rule(True, "passes; held-out error +7.1%", tilt, np.array([_tilt(0), _tilt(109)]), m)
    assert not ok and why.startswith("rejected: the folds disagree") and "held-out error +7.1%" in why
    ok, why = agreement_rule(True, "passes; held-out error +30%", tilt, np.array([_tilt(0), _tilt(20)]), m)
    assert ok and why.startswith("passes; ") and "fold agreement: largest angle between fold departures 20.0° (< 90°)" in why
    ok, why = agreement_rule(False, "rejected: fall below 5%", tilt, np.array([_tilt(0), _tilt(20)]), m)
    assert not ok and why.startswith("rejected: fall below 5%")
    # one split (a single value): the rule does not apply
    assert agreement_rule(True, "passes; x", tilt, np.array([_tilt(0)]), m) == (True, "passes; x")


def test_reason_does_not_round_an_agreeing_angle_up_to_the_threshold():
    tilt, m = REGISTRY["table_tilt"], _model()
    ok, why = fold_agreement(tilt, np.array([_tilt(0), _tilt(89.5)]), m)
    assert ok and "89.5° (< 90°)" in why
