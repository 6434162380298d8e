"""TrackingConfig refuses settings it would otherwise ignore or fail on mid-run."""

from dataclasses import replace

import pytest

from service.tracking import TrackingConfig


def test_defaults_and_fast_are_valid():
    assert TrackingConfig().stage_set("degen_stages") == {"track", "ba", "refine", "final"}
    assert TrackingConfig.fast().stage_set("degen_stages") == {"track", "ba", "refine", "final"}
    assert replace(TrackingConfig(), degen_stages="").stage_set("degen_stages") == set()


@pytest.mark.parametrize("change, words", [
    ({"degen_stages": "track,bundle"}, ["degen_stages", "bundle"]),
    ({"max_rate_deg": float("nan")}, ["max_rate_deg"]),
])
def test_bad_settings_are_refused_with_the_field_named(change, words):
    with pytest.raises(ValueError) as e:
        replace(TrackingConfig(), **change)
    assert all(w in str(e.value) for w in words), str(e.value)
