"""Tiny synthetic sessions shared by the synthetic-lab tests (generated once per test session)."""

import pytest

from service.synth import SynthSpec, make_session


@pytest.fixture(scope="session")
def clean_tiny(tmp_path_factory):
    """Tiny box push, noise off, no occlusion."""
    d = tmp_path_factory.mktemp("synth_clean")
    spec = SynthSpec(object="baking_box", interaction="push", seed=1, preset="tiny", noise=False)
    return spec, make_session(spec, d / "box_push")


@pytest.fixture(scope="session")
def noisy_tiny(tmp_path_factory):
    """Tiny bottle topple, noise on, heavy occlusion, a few hidden effects, undeclared mass and table."""
    from service.synth import HiddenEffects

    d = tmp_path_factory.mktemp("synth_noisy")
    spec = SynthSpec(
        object="bottle", interaction="topple", seed=2, preset="tiny", noise=True, occlusion="heavy",
        effects=HiddenEffects(restitution=0.3, clock_offset=0.0432, friction_object_table=0.4),
        declare_mass=False, declare_table_height=False, table_height=None,
    )
    return spec, make_session(spec, d / "bottle_topple")
