"""The held-out error where an effect acts (issue #6's third criterion, docs/residuals.md §1): the error component
the effect declares (position, rotation or both) on the frames of its contact modes."""

import dataclasses

import numpy as np
import pytest

from service.report.json import residuals_section
from service.residuals import run
from service.residuals.effects import REGISTRY, Effect
from service.residuals.loop import Segment, acting_errors
from service.residuals.types import MODES, ResidualConfig, ResidualInputs
from tests.residuals.lab import cube_model
from tests.residuals.test_crossfit import H, _ballistic, _tosses


def test_each_effect_declares_the_component_it_acts_on():
    comp = {n: e.component for n, e in REGISTRY.items()}
    for n in ("gravity_scale", "time_scale", "table_tilt", "table_offset", "linear_damping"):
        assert comp[n] == "position", n  # a force through the centre of mass
    assert comp["angular_damping"] == "rotation"  # a torque about it
    for n in ("restitution", "friction_table", "friction_robot", "com_offset", "clock_offset"):
        assert comp[n] == "both", n  # a force at a contact point, or where/when the object is touched
    with pytest.raises(ValueError, match="component"):
        dataclasses.replace(REGISTRY["gravity_scale"], component="spin")
    assert isinstance(REGISTRY["gravity_scale"], Effect)


def _block(modes: list[str], tracked=None) -> Segment:
    T = len(modes)
    return Segment(0, 0, T, np.arange(T) * H, np.repeat(np.eye(4)[None], T, 0),
                   np.ones(T, bool) if tracked is None else np.asarray(tracked, bool),
                   np.array([MODES.index(m) for m in modes]), np.eye(4), np.zeros(3), np.zeros(3), None)


def test_acting_error_takes_the_component_on_the_frames_of_the_modes():
    modes = ["free_flight", "free_flight", "sliding", "rest", "impact", "free_flight", "rest"]
    seg = _block(modes, tracked=[1, 1, 1, 1, 1, 1, 0])
    pos = np.array([1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0])
    rot = np.array([100.0, 200.0, 400.0, 800.0, 1600.0, 3200.0, 6400.0])
    frames = [np.stack([pos, rot], 1)]
    frames[0][~seg.tracked] = np.nan  # as Evaluator.frame_split leaves untracked frames

    def acting(name):
        return float(acting_errors(frames, [seg], REGISTRY[name])[0])

    assert acting("gravity_scale") == pytest.approx(np.mean([1.0, 2.0, 32.0]))  # position, free flight
    assert acting("table_offset") == pytest.approx(8.0)  # position, rest (the untracked rest frame left out)
    assert acting("angular_damping") == pytest.approx(np.mean([100.0, 200.0, 400.0, 3200.0]))  # rotation, flight + sliding
    assert acting("linear_damping") == pytest.approx(np.mean([1.0, 2.0, 4.0, 32.0]))  # position, flight + sliding
    # restitution: both, every frame from the block's first impact on
    assert acting("restitution") == pytest.approx(np.mean([16.0 + 1600.0, 32.0 + 3200.0]))


@pytest.mark.parametrize("folds", [1, 2])
def test_the_loop_reports_gravity_on_the_position_error_of_its_frames(folds):
    cfg = dataclasses.replace(ResidualConfig.fast(), candidates=("gravity_scale",), max_effects=1, fit_maxiter=24,
                              folds=folds)
    out = run(ResidualInputs(cube_model(), _tosses(12, 0.9, seed=5, spin=0.7), -10.0, simulate=_ballistic), cfg)
    assert out.accepted == ("gravity_scale",), [c.reason for c in out.candidates]
    c = out.candidates[0]
    assert c.acts_on == {"modes": ["free_flight"], "component": "position"}
    # the scalar error on its frames = position + rho * angle; the rotation part, which gravity cannot change, is
    # the same before and after and is left out of the error where it acts
    rot_before = c.heldout_error_before - c.heldout_acting_before
    rot_after = c.heldout_error_after - c.heldout_acting_after
    assert rot_before > 0.4 * c.heldout_error_before
    assert rot_after == pytest.approx(rot_before, rel=1e-9)
    r_acting = c.heldout_acting_after / c.heldout_acting_before
    assert r_acting < 0.6 and c.heldout_error_after / c.heldout_error_before > 2 * r_acting
    # carried into report.json (both writers) and the per-round record
    rep = out.report()["candidates"][0]
    assert rep["acts_on"]["component"] == "position" and rep["heldout_acting_after"] == pytest.approx(c.heldout_acting_after)
    sec = residuals_section(out, None)["candidates"][0]
    assert sec["heldout_acting_before"] == pytest.approx(c.heldout_acting_before)
    assert out.by_mode["rounds"][0]["heldout_acting_after"] == pytest.approx(c.heldout_acting_after)
