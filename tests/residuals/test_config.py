"""ResidualConfig refuses launch and bound settings that cannot work, naming the field."""

from dataclasses import replace

import pytest

from service.residuals.types import ResidualConfig


def test_presets_are_valid():
    assert ResidualConfig().launch_speed > ResidualConfig.fast().launch_rest_speed


@pytest.mark.parametrize("change, word", [
    ({"launch_speed": 0.0}, "launch_speed"),
    ({"launch_rest_speed": 0.2}, "launch_rest_speed"),  # above the launch speed: no launch could start at rest
    ({"robot_smooth_s": -0.01}, "robot_smooth_s"),
    ({"max_base_error_rel_learned": float("nan")}, "max_base_error_rel_learned"),
    ({"segment_s": 0.0}, "segment_s"),  # no block would hold a frame
    ({"rot_scale_m": -0.05}, "rot_scale_m"),
    ({"min_segment_frames": 1}, "min_segment_frames"),
    ({"fit_maxiter": 2.5}, "fit_maxiter"),
    ({"max_train_segments": 0}, "max_train_segments"),
    ({"seed": -1}, "seed"),
    ({"heldout_fraction": 1.0}, "heldout_fraction"),  # nothing left to fit on
    ({"alpha": 0.0}, "alpha"),  # no test could pass
    ({"sim_substep_s": float("nan")}, "sim_substep_s"),
    ({"rest_speed": 0.0}, "rest_speed"),
    ({"tie_tol_rel": -0.1}, "tie_tol_rel"),
    ({"alpha": "0.05"}, "alpha"),  # a string from a config file: refused naming the field, not a TypeError
    ({"segment_s": "0.3"}, "segment_s"),
    ({"restitution_threshold_mps": -0.05}, "restitution_threshold_mps"),
    ({"restitution_threshold_mps": float("nan")}, "restitution_threshold_mps"),
])
def test_bad_settings_are_refused(change, word):
    with pytest.raises(ValueError, match=word):
        replace(ResidualConfig(), **change)
