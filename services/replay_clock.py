"""When camera replay publishes, and under which frame ids: pacing and loop renumbering.

Two small pieces the replay loop asks before every message. :class:`Renumbering` keeps frame ids
and capture stamps increasing across ``--loop``: the first pass keeps the recording's own values
(so its bytes can go out untouched), each later pass is shifted to start one frame after the
previous pass ended. :class:`Pacer` turns those stamps into wall-clock publish times scaled by
``rate`` (0 = as fast as possible); since it sees the shifted stamps, loops play on without a gap.
"""

from __future__ import annotations

import threading
import time


class Renumbering:
    """Maps (pass, recorded frame id, recorded stamp) to the ids and stamps that go on the bus."""

    def __init__(self) -> None:
        self.frame_offset = 0
        self.stamp_offset = 0
        self._first_pass = True
        self._min_id: int | None = None
        self._min_stamp: int | None = None
        self._max_id = -1
        self._max_stamp = 0
        self._ids_seen: set[int] = set()
        self._period = 0

    @property
    def identity(self) -> bool:
        """True while ids and stamps go out as recorded (the first pass)."""
        return self.frame_offset == 0 and self.stamp_offset == 0

    def apply(self, frame_id: int, stamp_ns: int) -> tuple[int, int]:
        if self._first_pass:
            self._min_id = frame_id if self._min_id is None else min(self._min_id, frame_id)
            self._min_stamp = stamp_ns if self._min_stamp is None else min(self._min_stamp, stamp_ns)
            self._ids_seen.add(frame_id)
        new_id, new_stamp = frame_id + self.frame_offset, stamp_ns + self.stamp_offset
        self._max_id = max(self._max_id, new_id)
        self._max_stamp = max(self._max_stamp, new_stamp)
        return new_id, new_stamp

    def next_pass(self) -> None:
        """Shift the next pass to follow the one just played, one frame period later."""
        if self._min_id is None or self._min_stamp is None:
            return
        if self._first_pass:
            frames = len(self._ids_seen)
            span = self._max_stamp - self._min_stamp
            self._period = span // (frames - 1) if frames > 1 else 0
            self._first_pass = False
        self.frame_offset = self._max_id + 1 - self._min_id
        self.stamp_offset = self._max_stamp + self._period - self._min_stamp


class Pacer:
    """Sleeps until a stamp's moment comes, at ``rate`` times the recorded speed."""

    def __init__(self, rate: float, stop: threading.Event) -> None:
        self.rate = rate
        self._stop = stop
        self._origin: tuple[float, int] | None = None

    def wait(self, stamp_ns: int) -> None:
        """Return when ``stamp_ns`` is due (at once with rate 0, or when ``stop`` is set)."""
        if self.rate <= 0:
            return
        if self._origin is None:
            self._origin = (time.monotonic(), stamp_ns)
            return
        wall0, stamp0 = self._origin
        delay = wall0 + (stamp_ns - stamp0) / 1e9 / self.rate - time.monotonic()
        if delay > 0:
            self._stop.wait(delay)
