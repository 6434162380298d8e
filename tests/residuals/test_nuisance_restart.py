"""Each hypothesis judged with its own nuisance corrections (``ResidualConfig.nuisance_restart``): a candidate's joint
refit with the corrections also starts from "no change", not only from the corrections fitted without it (which took
up part of the effect), and the better training objective is kept."""

import numpy as np
import pytest
import trimesh

from service.mesh import Mesh
from service.model import ObjectModel
from service.residuals.effects import REGISTRY
from service.residuals.loop import _fit_nuisance, _refine_joint
from service.residuals.types import ResidualConfig
from service.session.types import Friction

A_ABS, C_TRUE = 0.004, 0.05  # m: the table offset that mimics the missing clock offset; s: the true clock offset


def _loss(a: float, c: float) -> float:
    """A training error with two basins: without the clock offset a table 4 mm off takes up part of the effect
    (a shallow basin at (A_ABS, 0)); the right model is no correction and the clock offset (a deeper one at
    (0, C_TRUE))."""
    return float(1.0 - 0.3 * np.exp(-((a - A_ABS) / 0.004) ** 2 - (c / 0.03) ** 2)
                 - 0.8 * np.exp(-(a / 0.002) ** 2 - ((c - C_TRUE) / 0.02) ** 2))


class _LookalikeEvaluator:
    """Every block's error is ``_loss`` of the simulator's table offset and clock offset."""

    def errors(self, model, effects, segs, masks=None):
        return np.full(len(segs), _loss(effects.get("table_offset", 0.0), effects.get("clock_offset", 0.0)))


def _model() -> ObjectModel:
    m = Mesh.from_trimesh(trimesh.creation.box((0.1, 0.08, 0.06)))
    return ObjectModel(m, (), 0.5, True, np.zeros(3), np.diag([1e-3, 1.2e-3, 1.5e-3]), Friction(0.15, 0.15), {})


def test_config_checks_the_restart():
    assert ResidualConfig().nuisance_restart == "off"  # the default (docs/residuals.md §3b)
    for ok in ("off", "joint", "both"):
        assert ResidualConfig(nuisance_restart=ok).nuisance_restart == ok
    for bad in ("on", True, None, ""):
        with pytest.raises(ValueError, match="nuisance_restart"):
            ResidualConfig(nuisance_restart=bad)


def test_joint_refit_finds_the_hypothesis_own_corrections():
    model, ev, segs = _model(), _LookalikeEvaluator(), [None] * 4
    off = ResidualConfig(nuisance_maxiter=60, nuisance_restart="off")
    fix, e0, e1 = _fit_nuisance(["table_offset"], model, {}, ev, segs, off)
    a0 = fix["table_offset"][0]
    assert abs(a0 - A_ABS) < 1e-3 and e1 < 0.95 * e0  # without the effect the table takes it up
    eff = REGISTRY["clock_offset"]
    # off: refitted from the absorbed correction, the joint fit stays in its basin (the effect fitted at nothing)
    nuis, th = _refine_joint(fix, eff, (0.0,), {}, model, {}, ev, segs, off)
    assert abs(nuis["table_offset"][0] - A_ABS) < 1e-3 and abs(th[0]) < 0.01
    # joint: also from "no change", the deeper basin is found and kept: no correction, the true clock offset
    on = ResidualConfig(nuisance_maxiter=60, nuisance_restart="joint")
    nuis_on, th_on = _refine_joint(fix, eff, (0.0,), {}, model, {}, ev, segs, on)
    assert abs(nuis_on["table_offset"][0]) < 5e-4 and abs(th_on[0] - C_TRUE) < 0.005
    assert _loss(nuis_on["table_offset"][0], th_on[0]) < _loss(nuis["table_offset"][0], th[0]) - 0.3


def test_no_effect_fit_restart_is_never_worse():
    model, ev, segs = _model(), _LookalikeEvaluator(), [None] * 4
    fix, _, e1 = _fit_nuisance(["table_offset"], model, {}, ev, segs, ResidualConfig(nuisance_maxiter=4, nuisance_restart="off"))
    fix2, _, e2 = _fit_nuisance(["table_offset"], model, {}, ev, segs, ResidualConfig(nuisance_maxiter=4, nuisance_restart="both"))
    assert e2 <= e1
    assert abs(fix2["table_offset"][0] - A_ABS) <= abs(fix["table_offset"][0] - A_ABS)
    # "joint" leaves the "no effect" fit as it is
    fix3, _, e3 = _fit_nuisance(["table_offset"], model, {}, ev, segs, ResidualConfig(nuisance_maxiter=4, nuisance_restart="joint"))
    assert fix3 == fix and e3 == e1
