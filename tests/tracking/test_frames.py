"""Decoded frames kept during a run (service.tracking.frames.FrameCache): the session's values as fresh arrays,
each image decoded once while kept, memory bounded to the recent and the pinned frames; the stage's outputs do not
depend on it."""

import numpy as np
import pytest

from service.tracking import TrackingConfig, TrackingInputs, run
from service.tracking.frames import FrameCache


class _Counting:
    """A session of 6 frames of random images that counts its decodes."""

    name = "fake"
    n_frames = 6

    def __init__(self):
        rng = np.random.default_rng(0)
        self.d = rng.uniform(0.5, 1.0, (6, 12, 16)).astype(np.float32)
        self.m = rng.random((6, 12, 16)) > 0.5
        self.c = rng.integers(0, 255, (6, 12, 16, 3), dtype=np.uint8)
        self.calls = {"depth": 0, "mask": 0, "rgb": 0}

    def depth(self, i):
        self.calls["depth"] += 1
        return self.d[i].copy()

    def mask(self, i):
        self.calls["mask"] += 1
        return self.m[i].copy()

    def rgb(self, i):
        self.calls["rgb"] += 1
        return self.c[i].copy()


def test_same_values_as_fresh_arrays_decoded_once():
    s = _Counting()
    c = FrameCache(s, keep_last=2)
    a = c.depth(3)
    b = c.depth(3)
    np.testing.assert_array_equal(a, s.d[3])
    assert a.dtype == np.float32 and a.flags.writeable and a is not b and s.calls["depth"] == 1
    a[:] = 0  # a caller may change what it got: the next read is not affected
    np.testing.assert_array_equal(c.depth(3), s.d[3])
    np.testing.assert_array_equal(c.mask(3), s.m[3])
    np.testing.assert_array_equal(c.rgb(3), s.c[3])
    assert c.name == "fake" and c.n_frames == 6  # other attributes: the session's
    assert c.decoded == 3 and c.served == 5


def test_keeps_only_the_recent_and_the_pinned_frames():
    s = _Counting()
    c = FrameCache(s, keep_last=2, pinned=[0])
    for i in range(6):
        c.depth(i)
    assert set(c._frames) == {0, 4, 5}
    assert c.kept_bytes() == 3 * s.d[0].nbytes
    c.depth(0)
    c.depth(5)
    assert s.calls["depth"] == 6  # 0 pinned, 5 recent
    c.depth(1)
    assert s.calls["depth"] == 7  # 1 was dropped
    c.pin([2, 3])
    for _ in range(2):
        for i in (2, 3, 1):
            c.mask(i)
    assert s.calls["mask"] == 3
    c.repin([3])
    assert set(c._frames) == {3, 2, 1}  # 3 pinned, 2 and 1 the most recent
    with pytest.raises(ValueError, match="keep_last"):
        FrameCache(s, keep_last=-1)


def test_run_decodes_each_image_once_and_gives_the_same_outputs(tiny_push_session, monkeypatch):
    """The stage through the cache and through the bare session (a cache keeping nothing): identical outputs;
    with the cache no image is decoded twice."""
    import service.tracking as stage
    from service.tracking import frames as frames_mod

    s = tiny_push_session(16)
    cfg = TrackingConfig.fast()
    made = []

    class Recording(frames_mod.FrameCache):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made.append(self)

    monkeypatch.setattr(stage, "FrameCache", Recording)
    cached = run(TrackingInputs(s), cfg)
    (c,) = made
    assert c.decoded <= 3 * s.n_frames < c.served  # every frame tracked: the frames the later passes read were kept

    class NoKeep(frames_mod.FrameCache):
        def __init__(self, session, keep_last=2, pinned=()):
            super().__init__(session, keep_last=0)

        def repin(self, frames):
            pass

    monkeypatch.setattr(stage, "FrameCache", NoKeep)
    bare = run(TrackingInputs(s), cfg)
    np.testing.assert_array_equal(cached.X_WO, bare.X_WO)
    np.testing.assert_array_equal(cached.sdf.values, bare.sdf.values)
    np.testing.assert_array_equal(cached.visible_mesh.vertices, bare.visible_mesh.vertices)
    np.testing.assert_array_equal(cached.visible_points_O, bare.visible_points_O)


def test_frames_read_in_order_are_decoded_ahead_once():
    """Reading frames in order: frame i + 1 is decoded ahead (of the kinds read of frame i − 1), each image once,
    the values the session's; reading out of order decodes nothing ahead."""
    s = _Counting()
    c = FrameCache(s, keep_last=2)
    for i in range(3):
        c.depth(i)
        c.mask(i)
    c._ahead[3].result()  # frame 3 decoded ahead while frame 2 was read
    assert s.calls == {"depth": 4, "mask": 4, "rgb": 0}
    for i in range(3, 6):
        np.testing.assert_array_equal(c.depth(i), s.d[i])
        np.testing.assert_array_equal(c.mask(i), s.m[i])
        np.testing.assert_array_equal(c.rgb(i), s.c[i])  # not read of the frame before: decoded on demand
    assert s.calls == {"depth": 6, "mask": 6, "rgb": 3} and not c._ahead  # none past the last frame
    assert c.decoded == 15
    s2 = _Counting()
    c2 = FrameCache(s2, keep_last=2)
    for i in (0, 2, 4):
        c2.depth(i)
    assert not c2._ahead and s2.calls["depth"] == 3
