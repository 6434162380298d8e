"""The loop on synthetic-lab pushing sessions (the lab's physics: impedance-driven sphere, rolling resistance,
hidden effects in the sidecar only), with a model that carries the errors of a learned one.

Shortcut (speed): the session is not rendered and tracked; the loop gets the lab's object poses with
0.5 mm / 0.3° of noise (what tracking achieves on these sessions: 0.5 mm / 1° median) and the robot log as
robot.csv holds it. The model is the catalogue shape and declared mass with deliberate errors (6 % too large,
inertia × 1.3, CoM 5 mm off): the nuisance refit must absorb them, so that they are neither accepted as an
effect nor bias the effect's value. Nothing of the hidden effect reaches the inputs.
"""

import dataclasses

import pytest

from service.residuals import run
from service.residuals.effects import NUISANCE_LEARNED
from service.residuals.types import ResidualConfig, ResidualInputs
from service.synth.types import HiddenEffects, SynthSpec
from tests.residuals.synthlab import lab_session, perturbed_model

FRAMES = 360  # 12 s at 30 Hz: about 8 held-out blocks in robot contact


def _loop(effects: dict, seed: int = 502):
    lab = lab_session(SynthSpec(object="milk_carton", interaction="push", seed=seed, preset="tiny", n_frames=FRAMES,
                                effects=HiddenEffects(**effects)))
    model = perturbed_model(lab, scale=1.06, inertia_factor=1.3, com_shift=(0.004, -0.003, 0.0))
    cfg = dataclasses.replace(ResidualConfig.fast(), candidates=("clock_offset", "friction_table"), segment_s=0.3,
                              nuisance=NUISANCE_LEARNED, nuisance_maxiter=70)
    return run(ResidualInputs(model, (lab.trajectory,), lab.table_height, robot=(lab.robot,)), cfg), lab


def test_hidden_clock_offset_in_a_lab_session_is_found():
    out, lab = _loop({"clock_offset": 0.1})
    assert out.accepted == ("clock_offset",), [c.reason for c in out.candidates]
    assert abs(out.effects["clock_offset"] - 0.1) <= 0.25 * 0.1
    cand = next(c for c in out.candidates if c.effect == "clock_offset")
    assert cand.heldout_error_after <= 0.6 * cand.heldout_error_before
    assert out.error_after["scalar_m"] < out.by_mode["error_corrected"]["scalar_m"] < out.error_before["scalar_m"]
    # the model errors went into the corrections, which are reported and not put into the output model
    assert abs(out.corrections["geometry_scale_1"] - 1 / 1.06) < 0.03
    assert out.model.effects == {"clock_offset": out.effects["clock_offset"]}
    assert out.model.mass == pytest.approx(lab.mass * 1.0)
    assert "corrections" in out.report()


def test_plain_lab_session_with_a_wrong_model_accepts_nothing():
    out, _ = _loop({})
    assert out.accepted == (), [c.reason for c in out.candidates]
    assert out.corrections  # the model's own errors were refitted instead
    assert out.by_mode["error_corrected"]["scalar_m"] < 0.6 * out.error_before["scalar_m"]
