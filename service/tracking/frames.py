"""Decoded frames kept during one run of the tracking stage, so that each image is decoded once.

The stage reads a frame's depth, mask and colour image several times: the tracking loop reads the colour image
twice per frame (ORB features, spin-closure features) and the depth again for a keyframe's free space; frame 0 is
read again when the body frame is re-gauged; the visible-geometry passes (colour trim of the masks, SDF rays,
contradicted readings, evidence band, visible set) read the same ~30 frames up to four times each. Decoding a
640x480 PNG/JPEG costs milliseconds; copying the decoded array costs a fraction of one.

``FrameCache`` wraps a session: ``depth``, ``mask`` and ``rgb`` return what the session's own methods return
(equal values, dtype and shape, a fresh writable array on every call, so callers may change it), decoding a frame
only when it is not kept. Kept: the ``keep_last`` most recently read frames (the tracking loop reads frame i
several times in a row) and the frames ``pin``ned: ``run`` pins from the start the frames the visible-geometry
passes read when every frame is tracked (evenly spread, frame 0 among them, which the re-gauge reads again), and
after tracking the frames they will read (the same unless frames were lost); memory is bounded by (keep_last + pinned frames) x (depth 4 + colour 3 + mask 1 bytes per pixel),
about 2.4 MB per 640x480 frame. Every other attribute is the session's own.

Read-ahead: when frame i is read for the first time right after frame i − 1 (the tracking loop reads the frames in
order), frame i + 1's images of the kinds read of frame i − 1 are decoded on one background thread while frame i
is processed (the decoders release the GIL), so the tracking loop waits less for decoding on two cores. The arrays
are those the session's methods return, decoded once; the stage's outputs do not depend on it. One frame more is
held (the one read ahead).
"""

from __future__ import annotations

import weakref
from collections import OrderedDict
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Iterable

import numpy as np

class FrameCache:
    """A session whose decoded images are kept while needed (module docstring)."""

    def __init__(self, session, keep_last: int = 2, pinned: Iterable[int] = ()):
        if keep_last < 0:
            raise ValueError(f"FrameCache: keep_last must be >= 0, not {keep_last!r}")
        self._session = session
        self._keep_last = int(keep_last)
        self._pinned: set[int] = {int(i) for i in pinned}
        self._frames: OrderedDict[int, dict[str, np.ndarray]] = OrderedDict()  # least recently read first
        self.decoded = 0  # images decoded (calls of the session's own methods)
        self.served = 0  # images returned
        self._ahead: dict[int, Future] = {}  # frame -> its images being decoded ahead (module docstring)
        self._pool: ThreadPoolExecutor | None = None
        self._last_new: int | None = None  # the frame read last for the first time

    def pin(self, frames: Iterable[int]) -> None:
        """Keep ``frames`` from now on (in addition to the ones pinned before)."""
        self._pinned |= {int(i) for i in frames}

    def repin(self, frames: Iterable[int]) -> None:
        """Keep exactly ``frames`` (besides the most recent ones) from now on; other kept frames are dropped."""
        self._pinned = {int(i) for i in frames}
        self._evict()

    def kept_bytes(self) -> int:
        return sum(a.nbytes for e in self._frames.values() for a in e.values())

    def depth(self, i: int) -> np.ndarray:
        return self._get("depth", i)

    def mask(self, i: int) -> np.ndarray:
        return self._get("mask", i)

    def rgb(self, i: int) -> np.ndarray:
        return self._get("rgb", i)

    def _get(self, kind: str, i: int) -> np.ndarray:
        i = int(i)
        entry = self._frames.get(i)
        if entry is None:
            entry = self._frames[i] = self._take_ahead(i)
            prev = self._frames.get(i - 1) if self._last_new == i - 1 else None
            self._last_new = i
            if prev:
                self._read_ahead(i + 1, tuple(prev))
        else:
            self._frames.move_to_end(i)
        a = entry.get(kind)
        if a is None:
            a = entry[kind] = getattr(self._session, kind)(i)
            self.decoded += 1
        self.served += 1
        self._evict()
        return a.copy()

    def _read_ahead(self, i: int, kinds: tuple[str, ...]) -> None:
        """Decode frame i's images of ``kinds`` on the background thread (once; not past the last frame)."""
        n = getattr(self._session, "n_frames", None)
        if (n is not None and i >= n) or i in self._frames or i in self._ahead:
            return
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="frames-ahead")
            weakref.finalize(self, self._pool.shutdown, wait=False)
        for k in [k for k in self._ahead if k < i - 1]:  # never read: dropped
            del self._ahead[k]
        s = self._session
        self._ahead[i] = self._pool.submit(lambda: {k: getattr(s, k)(i) for k in kinds})

    def _take_ahead(self, i: int) -> dict[str, np.ndarray]:
        """Frame i's images decoded ahead ({} when it was not read ahead)."""
        fut = self._ahead.pop(i, None)
        if fut is None:
            return {}
        entry = fut.result()
        self.decoded += len(entry)
        return entry

    def __getstate__(self):
        d = dict(self.__dict__)
        d["_ahead"], d["_pool"] = {}, None
        return d

    def _evict(self) -> None:
        loose = [k for k in self._frames if k not in self._pinned]  # least recently read first
        for k in loose[:max(len(loose) - self._keep_last, 0)]:
            del self._frames[k]

    def __getattr__(self, name):
        if name.startswith("_"):  # not found on the instance itself (e.g. during unpickling): no delegation
            raise AttributeError(name)
        return getattr(self._session, name)
