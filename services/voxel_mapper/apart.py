"""Parts whose corners move apart across the line of sight are not joined into one object.

Colour flood fill often gives a walker beside a wall or a pole a cluster of his own, and then the
linkage of parts (linkage.py) joins it to the wall's, since the two touch along a whole face: on
held-out synthetic urban (seeds 7-10) that is how 119 of the walker-frames within 30 m lost a
cluster of their own, more than any other step (flood fill itself 62, the aggregation of small
clusters 24). The corners the stereo stage follows tell such parts apart: on urban-s7 frame 35 the
walker's 8 corners move across the line of sight at 0.57 m/s (doubt 0.06), the wall's 138 at 0.00
(doubt 0.08). So two parts, each with ``min_corners`` corners followed ``samples`` frames, are kept
apart when the medians of their corners' speeds across the line of sight differ by more than
``across_mps`` and by more than ``sigma_k`` of their joint doubt, and one of them stands (its
corners' median across the line of sight is slower than ``still_mps``): two parts of one walker,
each read with its own noise, then stay joined. Each part needs 5 corners
(``voxel.apart_min_corners``): with 3, a walker crossing 24-36 m ahead on fresh synthetic crossing
was parted from what he passed in some frames and not in others, and two tracks followed him, one
at 5-6 m/s.

Only the speed across the line of sight is judged. Along it, a corner's doubt is its range's, and
on KITTI tracking 0001 standing parts read 1-2 m/s apart along it in 17 of its first 31 frames
(a wall and the hedge before it), where across it nearly all of them read within 0.15 m/s of
standing; judged along it too, the run's objects in one cluster fell 80.2 -> 75.6 %
(docs/results/voxel.md, "Session 50").

Corners are followed from the frame they first lie in a voxel above the road for as long as the
stereo stage follows them, like the ones the mapper passes on to the tracker; followed from the
frame they are found (most lie on the road), their histories cost 2.2 ms a frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.config import TrackerConfig
from common.corner_motion import CornerHistory, corner_velocity
from common.errors import ConfigError

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Mask = npt.NDArray[np.bool_]

@dataclass(frozen=True)
class ApartRule:
    """When two parts are kept apart by their corners (config ``voxel.apart_*``)."""

    min_corners: int = 0  # corners each part needs for an opinion; 0: parts never kept apart
    across_mps: float = 0.4  # their medians across the line of sight differ by more than this ...
    sigma_k: float = 2.5  # ... and by more than this many of their joint doubts
    still_mps: float = 0.2  # ... and one of them is slower than this across it (0: no part need stand)
    samples: int = 3  # frames a corner must have been followed for its velocity
    # a corner's position doubt across the line of sight (m): the tracker's (``tracker.corner_across_std_m``)
    across_std_m: float = TrackerConfig.corner_across_std_m

    def __post_init__(self) -> None:
        if self.min_corners < 0 or self.across_mps < 0.0 or self.sigma_k < 0.0 or self.still_mps < 0.0:
            raise ConfigError("voxel.apart_min_corners, apart_across_mps, apart_sigma_k, apart_still_mps must be >= 0")
        if self.min_corners > 0 and self.samples < 2:
            raise ConfigError(f"voxel.apart_samples must be >= 2 (a line through positions), got {self.samples}")


NEVER_APART = ApartRule()


@dataclass(frozen=True)
class Apart:
    """This frame's opinion of each part (flood-fill label): whether its corners have one, and what it is."""

    rule: ApartRule
    known: Mask  # (n,) parts with ``rule.min_corners`` corners or more
    across: F64  # (n,) median speed of their corners across the line of sight (signed, m/s)
    sigma: F64  # (n,) its doubt

    def __call__(self, a: I64, b: I64) -> Mask:
        """Which pairs of parts (a[i], b[i]) are kept apart."""
        r = self.rule
        differ = np.abs(self.across[a] - self.across[b])
        apart = self.known[a] & self.known[b] & (differ > np.maximum(r.across_mps, r.sigma_k * np.hypot(
            self.sigma[a], self.sigma[b])))
        if r.still_mps > 0.0:
            apart &= np.minimum(np.abs(self.across[a]), np.abs(self.across[b])) < r.still_mps
        return apart


class PartMotion:
    """The corners above the road, followed from frame to frame, and the parts they keep apart."""

    def __init__(self, rule: ApartRule) -> None:
        self.rule = rule
        self.history = CornerHistory()
        self._followed = np.zeros(0, dtype=np.int64)  # ids followed last frame
        self._world = -1
        self._generation = 0  # a new one forgets every history
        self._start_ns = 0
        self._last_ns: int | None = None

    @property
    def on(self) -> bool:
        return self.rule.min_corners > 0

    def follow(self, ids: I64, corners: F64, std: F64, above_road: Mask, stamp_ns: int, world_epoch: int) -> None:
        """This frame's corners (world frame) to follow: those in a voxel above the road
        (``above_road``), and those followed last frame.

        A frame stamped before the last one (a recording replayed again) starts every history
        afresh, as a new world does.
        """
        if self._last_ns is None or stamp_ns < self._last_ns or world_epoch != self._world:
            self._generation += 1
            self._start_ns, self._world = stamp_ns, world_epoch
            self._followed = self._followed[:0]
        self._last_ns = stamp_ns
        ids = np.asarray(ids, dtype=np.int64)
        followed = np.asarray(above_road, dtype=bool) | np.isin(ids, self._followed)
        self._followed = ids[followed]
        clock = (stamp_ns - self._start_ns) * 1e-9
        self.history.update(ids[followed], corners[followed], np.asarray(std)[followed], clock, self._generation)

    def judge(self, coords: npt.NDArray[np.integer], labels: npt.NDArray[np.int32], n_parts: int, eye: F64,
              edge: float) -> Apart:
        """Each part's corners (those in its voxels this frame) and their median speed across the line
        of sight from ``eye``; ``coords`` are the map's voxels, ``labels`` their parts (-1: none)."""
        members = np.flatnonzero(labels >= 0)
        order = members[np.argsort(labels[members], kind="stable")]
        counts = np.bincount(labels[members], minlength=n_parts)
        c = corner_velocity(self.history, np.asarray(coords[order], dtype=np.int64), counts, np.arange(n_parts),
                            n_parts, edge, self.rule.samples, eye, self.rule.across_std_m)
        return Apart(self.rule, c.count >= self.rule.min_corners, c.across, c.across_sigma)

