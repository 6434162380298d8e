"""Shared inputs of the tracking tests."""

import pytest

from service.session import load_session


@pytest.fixture(scope="session")
def tiny_push_session(tmp_path_factory):
    """``tiny_push_session(n_frames)``: a small, heavily occluded, noisy baking-box push (seed 101, 240×180),
    made once per frame count and loaded as a Session."""
    from service.synth import SynthSpec, make_session

    made = {}

    def get(n_frames: int):
        if n_frames not in made:
            spec = SynthSpec(object="baking_box", interaction="push", seed=101, preset="tiny", occlusion="heavy",
                             noise=True, resolution=(240, 180), n_frames=n_frames)
            res = make_session(spec, tmp_path_factory.mktemp(f"push{n_frames}") / "s")
            made[n_frames] = load_session(res.session_dir, "test")
        return made[n_frames]

    return get
