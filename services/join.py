"""Pairing a stage's inputs by frame id: the voxel mapper's points + ego, the tracker's clusters + ego.

The inputs of one frame come from different services and arrive in any order, so each waits in
a small bounded buffer until its partners with the same ``frame_id`` are there. Frame ids are
monotonic and every publisher's messages arrive in order, so once frame k is complete a partial
frame older than k can never complete (its missing part was dropped upstream): it is evicted
at once. Beyond ``capacity`` pending frames the oldest is evicted too. Evictions are counted,
never silent. Pure: no bus, so it is tested on its own.

An *optional* input (the odometry's INS samples) is taken when it is there by the time the
required ones complete a frame, and never waited for: a frame is not lost to a sensor that
dropped a sample, it goes on without it (counted). A replay publishes the sample before its
frame, so in lockstep it is always there first. A sample that comes after its frame went waits
as a partial frame that cannot complete, and is evicted like one.
"""

from __future__ import annotations

from collections.abc import Sequence

from common.messages import Message


class FrameJoiner:
    """Collects one message per input name for each frame id and hands out complete frames."""

    def __init__(self, names: Sequence[str], capacity: int = 16, optional: Sequence[str] = ()) -> None:
        if not names:
            raise ValueError("a joiner needs at least one input")
        self.names = tuple(names)
        self.optional = frozenset(optional)
        self.required = tuple(n for n in self.names if n not in self.optional)
        if not self.required or not self.optional <= set(self.names):
            raise ValueError(f"optional inputs {sorted(self.optional)} must be some, not all, of {self.names}")
        self.capacity = max(1, capacity)
        self._pending: dict[int, dict[str, Message]] = {}
        self.evicted = 0  # partial frames given up on
        self.replaced = 0  # a second message for an input of a pending frame (the newer one is kept)
        self.without_optional = 0  # frames handed out before an optional input arrived

    def add(self, name: str, msg: Message) -> dict[str, Message] | None:
        """Add one input message; return the frame's inputs (by name) once the required ones are there."""
        if name not in self.names:
            raise ValueError(f"unknown input {name!r}; this joiner takes {self.names}")
        parts = self._pending.setdefault(msg.frame_id, {})
        if name in parts:
            self.replaced += 1
        parts[name] = msg
        if all(n in parts for n in self.required):
            del self._pending[msg.frame_id]
            self._evict_older_than(msg.frame_id)
            self.without_optional += len(parts) < len(self.names)
            return parts
        while len(self._pending) > self.capacity:
            del self._pending[min(self._pending)]
            self.evicted += 1
        return None

    def pending(self, name: str | None = None) -> int:
        """Frames waiting for a partner (only those already holding ``name``, if given)."""
        if name is None:
            return len(self._pending)
        return sum(1 for parts in self._pending.values() if name in parts)

    def _evict_older_than(self, frame_id: int) -> None:
        stale = [k for k in self._pending if k < frame_id]
        for k in stale:
            del self._pending[k]
        self.evicted += len(stale)
