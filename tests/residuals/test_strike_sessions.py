"""The loop on synthetic-lab *strike* sessions: one hidden effect each, never told to the loop.

A strike (``SynthSpec.interaction = "strike"``) is an impulsive push: the impedance-driven sphere hits the resting
baking box at 0.4-0.7 m/s from a new heading every ~1.6 s and stops; the box slides free and comes to rest
under friction. The effects that quasi-static pushing hides show there: table friction (constant deceleration
mu g), linear damping (deceleration growing with the speed), a table tilt (deceleration depending on the
heading), a CoM offset (the spin and the path of an off-centre launch), a clock offset (the launch time against
the robot log; tested on pushing sessions in test_lab_sessions.py, on strikes in ``benchmarks/residuals.py
strike``), an object-robot friction other than the prior (the spin and heading a glancing strike gives), a
restitution (a central strike of the heavy sphere launches the box at about (1 + e) times the sphere's speed along
the normal; the lab and the loop's replay both split the step at the time of impact, so the contact starts at the
touch and the bounce is the declared one). Each
test restricts the candidates to the true effect and the ones it is most easily confused with, and checks: the true
effect is the one accepted, its value within 25 % of the truth, and the held-out rollout error of the free-sliding
frames (restitution: of its own frames, every frame from a block's first strike on, issue #6's error where it acts)
after <= 0.6 x before. A plain session accepts nothing.

Shortcut (speed), as in ``test_lab_sessions.py``: the session is not rendered nor tracked; the loop gets the lab's
poses with 0.5 mm / 0.3 deg of noise and the robot log as robot.csv holds it (0.2 mm sensor noise, shifted time
stamps). The model is the catalogue shape, mass and uniform-density inertia with the declared friction (0.15);
no nuisance refit (with a model carrying learned-model errors the refit soaks up part of a friction change: see
docs/residuals.md). Angular damping is not tested: on strikes it is fitted high (within 25 % on 2 of 5 and 1 of 2
catalogue sessions; docs/residuals-findings.md).
"""

import dataclasses

import numpy as np
import pytest

from service.residuals import run
from service.residuals.types import ResidualConfig, ResidualInputs
from service.synth.types import HiddenEffects, SynthSpec
from tests.residuals.synthlab import lab_session, perturbed_model

SEED = 502
FRAMES = 900  # 30 s at 30 Hz: ~19 strikes, ~8 held-out launch blocks
MU = 0.15  # declared (and, unless hidden, true) object-table friction


def _loop(effects: dict, candidates: tuple[str, ...], **cfg):
    lab = lab_session(SynthSpec(object="baking_box", interaction="strike", seed=SEED, preset="tiny", n_frames=FRAMES,
                                friction_object_table=MU, effects=HiddenEffects(**effects)))
    # fast() with 10 training blocks and 24 evaluations per fit: with 6 / 16 the fits drawn among the regular
    # blocks missed (linear damping 2.8 for 2.0, CoM 32 % off on seed 602)
    c = dataclasses.replace(ResidualConfig.fast(), candidates=candidates, segment_s=0.3, nuisance=(), fit_maxiter=24,
                            max_train_segments=10, **cfg)
    out = run(ResidualInputs(perturbed_model(lab), (lab.trajectory,), lab.table_height, robot=(lab.robot,)), c)
    return out


def _slide_err(out, when):
    return out.by_mode[f"rollout_{when}"]["sliding"]["pos_err_m"]


def _check(out, name):
    assert out.accepted == (name,), [c.reason for c in out.candidates]
    # the free slides are where every one of these effects acts
    assert _slide_err(out, "after") <= 0.6 * _slide_err(out, "before")
    cand = next(c for c in out.candidates if c.effect == name)
    assert cand.heldout_error_after < cand.heldout_error_before
    assert out.error_after["scalar_m"] < out.error_before["scalar_m"]


@pytest.mark.parametrize(
    "effects, name, key, truth, candidates",
    [
        ({"friction_object_table": 0.3}, "friction_table", "friction_object_table", 0.3,
         ("friction_table", "linear_damping", "table_tilt")),
        ({"linear_damping": 2.0}, "linear_damping", "linear_damping", 2.0,
         ("linear_damping", "friction_table", "table_tilt")),
    ],
)
def test_hidden_effect_in_strike_session(effects, name, key, truth, candidates):
    out = _loop(effects, candidates)
    _check(out, name)
    assert abs(out.effects[key] - truth) <= 0.25 * abs(truth - (MU if name == "friction_table" else 0.0))


def test_hidden_table_tilt_in_strike_session():
    out = _loop({"table_tilt": (0.05, 0.0)}, ("table_tilt", "friction_table", "linear_damping"))
    _check(out, "table_tilt")
    fitted = np.array([out.effects["table_tilt_x"], out.effects["table_tilt_y"]])
    assert np.linalg.norm(fitted - [0.05, 0.0]) <= 0.25 * 0.05
    # accepted with its signature: better on blocks moving downhill and on blocks moving uphill
    cand = next(c for c in out.candidates if c.effect == "table_tilt")
    assert "downhill blocks" in cand.reason


def test_hidden_com_offset_in_strike_session():
    truth = np.array([0.012, -0.01, 0.0])
    out = _loop({"com_offset": tuple(truth)}, ("com_offset", "friction_table", "table_tilt"))
    _check(out, "com_offset")
    fitted = np.array([out.effects[f"com_offset_{a}"] for a in "xyz"])
    # the horizontal offset shows in the spin and path of every launch; its height hardly shows on a table
    assert np.linalg.norm(fitted[:2] - truth[:2]) <= 0.25 * np.linalg.norm(truth)
    assert out.model.com_O == pytest.approx(fitted)


def test_hidden_robot_friction_in_strike_session():
    # object-robot friction 0.5 against the declared 0.15: a glancing strike's tangential impulse through mu_OR turns
    # the box and bends its heading; the loop fits the factor on the prior (truth 0.5 / 0.15)
    truth = 0.5 / 0.15
    out = _loop({"friction_object_robot": 0.5}, ("friction_robot", "friction_table", "com_offset"))
    _check(out, "friction_robot")
    assert abs(out.effects["friction_scale_robot"] - truth) <= 0.25 * (truth - 1.0)
    assert out.model.friction.object_robot == pytest.approx(0.15 * out.effects["friction_scale_robot"])
    assert out.model.friction.object_table == MU


def test_hidden_restitution_in_strike_session():
    # restitution 0.3 (declared 0): the box leaves a strike at (1 + e) times the sphere's speed, so every slide is
    # longer and faster at the start. Its look-alikes change the launch or the slide after it in the same direction:
    # a lower table friction lengthens every slide; a larger object-robot friction adds tangential impulse at a
    # glancing strike (speed, spin, heading). Judged where restitution acts: every frame from a block's first strike on
    truth = 0.3
    out = _loop({"restitution": truth}, ("restitution", "friction_table", "friction_robot"))
    assert out.accepted == ("restitution",), [c.reason for c in out.candidates]
    cand = next(c for c in out.candidates if c.effect == "restitution")
    assert cand.acts_on["modes"] == ["impact", "robot_contact"]
    assert cand.heldout_acting_after <= 0.6 * cand.heldout_acting_before
    assert out.error_after["scalar_m"] < out.error_before["scalar_m"]
    assert abs(out.effects["restitution"] - truth) <= 0.25 * truth
    # carried by the model the simulator is given: its effects, nothing else changed
    assert out.model.effects["restitution"] == pytest.approx(out.effects["restitution"])
    assert out.model.friction.object_table == MU
    assert out.model.friction.object_robot == pytest.approx(0.15)


def test_plain_strike_session_accepts_nothing():
    out = _loop({}, ("friction_table", "linear_damping", "table_tilt"))
    assert out.accepted == (), [c.reason for c in out.candidates]
    assert out.by_mode["rollout_before"]["sliding"]["frames"] > 20  # the session did slide the box
