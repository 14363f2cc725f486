"""Which frames the tracker takes, and how long since the last one it took: its input guards.

A frame of an older world epoch, or whose id is not newer than the last, is stale: ignored and
counted (``stale_frames``). A newer epoch is a new world (``epoch_resets``), whose tracks the
tracker starts again. A gap in frame ids is predicted through with the stamp difference
(``gaps``, ``gap_frames``), falling back to the nominal period when stamps do not advance
(``bad_stamps``).
"""

from __future__ import annotations

from dataclasses import dataclass

from common.messages import Clusters


@dataclass
class FrameClock:
    """The last frame taken; ``counters`` is the tracker's, counted into here."""

    period_s: float  # time step when stamps cannot give one
    counters: dict[str, int]
    epoch: int | None = None
    last_frame: int | None = None
    last_stamp_ns: int = 0

    def stale(self, clusters: Clusters) -> tuple[bool, bool]:
        """(ignore this frame, it starts a new world)."""
        epoch = clusters.world_epoch
        if self.epoch is not None and epoch < self.epoch:
            self.counters["stale_frames"] += 1
            return True, False
        new_world = self.epoch is not None and epoch > self.epoch
        if new_world:
            self.counters["epoch_resets"] += 1
            self.last_frame = None
        self.epoch = epoch
        if self.last_frame is not None and clusters.frame_id <= self.last_frame:
            self.counters["stale_frames"] += 1
            return True, new_world
        return False, new_world

    def step(self, clusters: Clusters) -> tuple[float, int]:
        """Seconds and frames since the previous frame taken; this one is taken."""
        self.counters["frames"] += 1
        if self.last_frame is None:
            dt, elapsed = self.period_s, 1
        else:
            elapsed = clusters.frame_id - self.last_frame
            if elapsed > 1:
                self.counters["gaps"] += 1
                self.counters["gap_frames"] += elapsed - 1
            dt = (clusters.stamp_ns - self.last_stamp_ns) * 1e-9
            if not dt > 0.0:
                self.counters["bad_stamps"] += 1
                dt = elapsed * self.period_s
        self.last_frame, self.last_stamp_ns = clusters.frame_id, clusters.stamp_ns
        return dt, elapsed
