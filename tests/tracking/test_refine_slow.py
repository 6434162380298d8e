"""The refinement's small starting radius only for keyframes taken in slow motion (``refine_slow_deg``,
``tracker._slow_keyframe``, ``tracker._refine_keyframes``).

A keyframe whose tracked poses around it (± ``refine_slow_frames``) turn by at most ``refine_slow_deg`` per frame
starts at ``refine_slow_dist0``; one taken in a fall keeps ``refine_dist0`` (docs/tracking-findings.md, "Worst frames
of pivots just over 5°"). Checked: which keyframes get which radius, that a fall's keyframe 9 mm off is still brought
back while a resting one is kept, that 0 turns it off, and bad values.
"""

from dataclasses import replace

import numpy as np
import pytest

from service.tracking import TrackingConfig
from service.tracking import tracker
from service.tracking.tracker import _refine_keyframes, _slow_keyframe
from service.transforms import make_X, so3_exp

from tests.tracking.test_refine_dist0 import _icp_kw, _keyframes


def _track(n: int = 40, fall: tuple[int, int] = (20, 29), rate_deg: float = 10.0, jitter_deg: float = 0.8):
    """Poses X_WO (n,4,4): at rest with a per-frame jitter of ``jitter_deg`` alternating about x, and a turn about y
    of ``rate_deg`` per frame from frame fall[0] to fall[1] (a topple's fall)."""
    X = np.zeros((n, 4, 4))
    ang = 0.0
    for i in range(n):
        if fall[0] < i <= fall[1]:
            ang += rate_deg
        R = so3_exp(np.radians([jitter_deg / 2 * (-1) ** i, ang, 0.0]))
        X[i] = make_X(R, np.zeros(3))
    return X


def test_slow_frames_are_those_away_from_the_fall():
    cfg = replace(TrackingConfig(), refine_slow_deg=4.0)
    X = _track()
    slow = [_slow_keyframe(X, i, cfg) for i in range(len(X))]
    # frames 19..30 see a turn of 10° within ± 2 frames (turns from frame 20 to 29); the others only the 0.8° jitter (frame 0 and the last clipped)
    assert slow == [not (19 <= i <= 30) for i in range(len(X))]
    assert not any(_slow_keyframe(X, i, replace(cfg, refine_slow_deg=0.5)) for i in range(len(X)))


@pytest.mark.parametrize("slow_deg, expect", [(0.0, [0.015, 0.015]), (4.0, [0.006, 0.015])])
def test_each_keyframe_gets_its_radius(monkeypatch, slow_deg, expect):
    seen = []
    real = tracker.icp

    def spy(*a, **k):
        seen.append(k["dist0"])
        return real(*a, **k)

    monkeypatch.setattr(tracker, "icp", spy)
    cfg = replace(TrackingConfig(), refine_slow_deg=slow_deg)
    kfs = _keyframes(np.zeros(3))
    kfs[1].index, kfs[2].index = 5, 25  # at rest, in the fall
    _refine_keyframes(kfs, cfg, None, _icp_kw(cfg), _track())
    assert seen == expect


def test_a_falls_keyframe_is_still_corrected_a_resting_one_kept():
    """The same keyframe 9 mm off: taken in the fall it starts at 15 mm and is brought back; taken at rest it starts at
    6 mm and keeps its pose."""
    off = 0.009 * np.array([1.0, -1.0, 1.0])
    cfg = replace(TrackingConfig(), refine_slow_deg=4.0)
    for index, expect_back in [(25, True), (5, False)]:
        kfs = _keyframes(off)
        kfs[2].index = index
        _refine_keyframes(kfs, cfg, None, _icp_kw(cfg), _track())
        err = np.linalg.norm(kfs[2].X_WO[:3, 3])
        assert (err < 0.001) if expect_back else (err > 0.015), (index, err)


def test_off_by_default():
    cfg = TrackingConfig()
    assert cfg.refine_slow_deg == 0.0 and cfg.refine_dist0 == 0.015


@pytest.mark.parametrize("field, v", [("refine_slow_deg", -1.0), ("refine_slow_deg", float("nan")),
                                      ("refine_slow_deg", float("inf")), ("refine_slow_deg", True),
                                      ("refine_slow_frames", 0), ("refine_slow_frames", 1.5),
                                      ("refine_slow_frames", True), ("refine_slow_dist0", 0.005),
                                      ("refine_slow_dist0", float("nan")), ("refine_slow_dist0", True)])
def test_bad_values_are_refused(field, v):
    with pytest.raises(ValueError, match=field):
        replace(TrackingConfig(), **{field: v})


def test_from_start_a_keyframe_at_rest_after_the_fall_is_not_slow():
    """At rest after a fall the local turn is slow, but the pose was reached through the fall: with
    ``refine_slow_from_start`` only the frames before the fall (and not within 2 frames of it) count as slow."""
    X = _track()
    local = replace(TrackingConfig(), refine_slow_deg=4.0)
    start = replace(local, refine_slow_from_start=True)
    assert _slow_keyframe(X, 35, local) and not _slow_keyframe(X, 35, start)
    assert [_slow_keyframe(X, i, start) for i in range(len(X))] == [i < 19 for i in range(len(X))]


def test_from_start_must_be_a_bool():
    with pytest.raises(ValueError, match="refine_slow_from_start"):
        replace(TrackingConfig(), refine_slow_from_start=1)
