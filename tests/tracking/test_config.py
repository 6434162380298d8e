"""TrackingConfig refuses settings it would otherwise ignore or fail on mid-run."""

from dataclasses import replace

import pytest

from service.tracking import TrackingConfig


def test_defaults_and_fast_are_valid():
    assert replace(TrackingConfig()) == TrackingConfig()
    assert replace(TrackingConfig.fast()) == TrackingConfig.fast()


@pytest.mark.parametrize("change, words", [
    ({"max_rate_deg": float("nan")}, ["max_rate_deg"]),
    ({"sdf_silhouette_px": -1}, ["sdf_silhouette_px"]),
    ({"sdf_silhouette_px": 2.5}, ["sdf_silhouette_px"]),
    ({"sdf_silhouette_back": 0.02}, ["sdf_silhouette_back", "trunc"]),
    ({"sdf_silhouette_margin": -0.001}, ["sdf_silhouette_margin"]),
    ({"sdf_silhouette_drop": 1}, ["sdf_silhouette_drop"]),
    ({"resettle_box_face": 1}, ["resettle_box_face"]),
    ({"resettle_box_drop": 1}, ["resettle_box_drop"]),
    ({"resettle_box_flush": 1}, ["resettle_box_flush"]),
    ({"resettle_box_axis": "yes"}, ["resettle_box_axis"]),
    ({"lie_axis_ends": 1}, ["lie_axis_ends"]),
    ({"lie_axis_short": -0.001}, ["lie_axis_short"]),
    ({"lie_axis_min_shift": float("nan")}, ["lie_axis_min_shift"]),
    ({"lie_axis_spread": float("inf")}, ["lie_axis_spread"]),
    ({"resettle_box_rest": -0.001}, ["resettle_box_rest"]),
    ({"resettle_box_slide": 1}, ["resettle_box_slide"]),
    ({"resettle_box_slide_short": -0.01}, ["resettle_box_slide_short"]),
    ({"resettle_box_slide_short": float("nan")}, ["resettle_box_slide_short"]),
    ({"resettle_box_slide_frac": 1.5}, ["resettle_box_slide_frac"]),
    ({"resettle_box_slide_frac": True}, ["resettle_box_slide_frac"]),
    ({"resettle_box_slide_min": -0.001}, ["resettle_box_slide_min"]),
    ({"resettle_box_rest": float("nan")}, ["resettle_box_rest"]),
])
def test_bad_settings_are_refused_with_the_field_named(change, words):
    with pytest.raises(ValueError) as e:
        replace(TrackingConfig(), **change)
    assert all(w in str(e.value) for w in words), str(e.value)
