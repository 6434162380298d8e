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
])
def test_bad_settings_are_refused(change, word):
    with pytest.raises(ValueError, match=word):
        replace(ResidualConfig(), **change)
