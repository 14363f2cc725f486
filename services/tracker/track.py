"""Every track of the three queues, stored column-wise so a frame's maths runs on whole arrays.

A row is one track: its queue, its Kalman state, the appearance the association compares with
(colour, size, density, a running mean of the clusters it took), and the last cluster's box and
centroid, which the reported box and the measurement's trust are taken from.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from services.tracker.motion_state import SLIDE_SMOOTHING
from services.tracker.motion_window import SIZE as WINDOW
from services.tracker.observations import Observations

NDArray = npt.NDArray[Any]

ACCEPTANCE, TRACKED, GHOST = 0, 1, 2
QUEUE_NAMES: tuple[str, ...] = ("acceptance", "tracked", "ghost")


def _empty(*shape: int, dtype: Any = np.float64) -> Any:
    return field(default_factory=lambda: np.zeros((0, *shape), dtype=dtype))


@dataclass
class TrackTable:
    """Column store of tracks; every field has the track axis first."""

    ids: NDArray = _empty(dtype=np.int64)
    queue: NDArray = _empty(dtype=np.int8)
    x: NDArray = _empty(6)  # Kalman state
    p: NDArray = _empty(6, 6)  # Kalman covariance
    offset: NDArray = _empty(3)  # last cluster centroid minus the filter position it gave
    side: NDArray = _empty(dtype=np.int8)  # which side face of its clusters the filter follows (anchor.py)
    end: NDArray = _empty(dtype=bool)  # it follows its clusters' far end: their near end is cut by the image
    hits: NDArray = _empty(dtype=np.int64)  # consecutive frames seen
    misses: NDArray = _empty(dtype=np.int64)  # frames since last seen
    age: NDArray = _empty(dtype=np.int64)  # frames since birth
    moving: NDArray = _empty(dtype=bool)
    nis: NDArray = _empty()  # running mean of the normalised innovation: > 1 = jumpier than modelled
    rgb: NDArray = _empty(3)
    hsl: NDArray = _empty(3)
    extent: NDArray = _empty(3)
    extent_slow: NDArray = _empty(3)  # slow average of the box extent: steady growth shows against it
    across: NDArray = _empty()  # its last cluster's points' width across the line of sight (m, anchor.py)
    across_slow: NDArray = _empty()  # ... and their slow average, as extent_slow
    depth: NDArray = _empty()  # how deep its last cluster's points' middle half lies along the line of sight
    density: NDArray = _empty()
    volume: NDArray = _empty()
    floor: NDArray = _empty()  # its clusters' lowest voxel above the road (m), smoothed as its size
    centroid: NDArray = _empty(3)  # last cluster's
    bbox_min: NDArray = _empty(3)
    bbox_max: NDArray = _empty(3)
    window: NDArray = _empty(WINDOW, 2)  # last faces followed, world x, y (motion_window.py)
    window_far: NDArray = _empty(WINDOW, 2)  # the far ends of the same clusters
    window_t: NDArray = _empty(WINDOW)  # their times (s, tracker clock)
    window_n: NDArray = _empty(dtype=np.int64)  # how many of them belong to the current cluster shape
    parted: NDArray = _empty(dtype=bool)  # measured this frame on a part of a shared cluster (parting.py)
    corner_velocity: NDArray = _empty(2)  # median velocity of the followed corners on it (keypoint_motion.py)
    corner_sigma: NDArray = _empty()  # ... its doubt (m/s)
    corner_count: NDArray = _empty(dtype=np.int64)  # ... and how many corners; 0: none, no opinion
    corner_across: NDArray = _empty()  # their median speed across the line of sight (signed, m/s)
    corner_across_sigma: NDArray = _empty()  # ... its doubt (m/s)
    corner_mover: NDArray = _empty(3)  # their largest group moving across it: how many, speed (signed), width (m)

    def __len__(self) -> int:
        return int(self.ids.shape[0])

    def keep(self, mask: NDArray) -> None:
        """Drop the rows where ``mask`` is False."""
        if mask.all():  # most frames drop nothing; copying 24 columns costs 30 µs
            return
        for f in dataclasses.fields(self):
            setattr(self, f.name, getattr(self, f.name)[mask])

    def extend(self, other: TrackTable) -> None:
        """Append the rows of ``other``."""
        for f in dataclasses.fields(self):
            setattr(self, f.name, np.concatenate([getattr(self, f.name), getattr(other, f.name)]))


def born(ids: NDArray, obs: Observations, p: NDArray, clock: float, parted: NDArray) -> TrackTable:
    """New acceptance tracks, one per observation: at rest at the point followed, covariance ``p``.

    Each speed window starts with this frame's face at time ``clock``; ``parted`` says which were
    measured on a part of a shared cluster (parting.py).
    """
    n = len(obs)
    window = np.zeros((n, WINDOW, 2))
    window[:, -1] = obs.anchor[:, 0:2]
    window_far = np.zeros((n, WINDOW, 2))
    window_far[:, -1] = (obs.anchor + obs.far)[:, 0:2]
    return TrackTable(
        ids=ids,
        queue=np.zeros(n, dtype=np.int8),
        x=np.hstack([obs.followed, np.zeros((n, 3))]),
        p=p,
        offset=obs.centroid - obs.followed,
        side=obs.side.copy(),
        end=obs.cut.copy(),
        hits=np.ones(n, dtype=np.int64),
        misses=np.zeros(n, dtype=np.int64),
        age=np.ones(n, dtype=np.int64),
        moving=np.zeros(n, dtype=bool),
        nis=np.ones(n),
        rgb=obs.rgb.copy(),
        hsl=obs.hsl.copy(),
        extent=obs.extent,
        extent_slow=obs.extent,
        across=obs.across.copy(),
        across_slow=obs.across.copy(),
        depth=obs.depth.copy(),
        density=obs.density.copy(),
        volume=obs.volume.copy(),
        floor=obs.floor.copy(),
        centroid=obs.centroid.copy(),
        bbox_min=obs.bbox_min.copy(),
        bbox_max=obs.bbox_max.copy(),
        window=window,
        window_far=window_far,
        window_t=np.full((n, WINDOW), clock),
        window_n=np.ones(n, dtype=np.int64),
        parted=parted.copy(),
        corner_velocity=np.zeros((n, 2)),
        corner_sigma=np.full(n, np.inf),
        corner_count=np.zeros(n, dtype=np.int64),
        corner_across=np.zeros(n),
        corner_across_sigma=np.full(n, np.inf),
        corner_mover=np.zeros((n, 3)),
    )


def follow_appearance(t: TrackTable, rows: NDArray, obs: Observations, weight: float) -> None:
    """The seen tracks ``rows`` take in their clusters ``obs``: colour, size, density and floor
    move ``weight`` of the way (what association compares), the slow extent and width across the
    line of sight a ``SLIDE_SMOOTHING`` of it (what the slide is read from, motion_state.py)."""
    t.rgb[rows] += weight * (obs.rgb - t.rgb[rows])
    hue_step = (obs.hsl[:, 0] - t.hsl[rows, 0] + 0.5) % 1.0 - 0.5  # the short way round
    t.hsl[rows, 1:3] += weight * (obs.hsl[:, 1:3] - t.hsl[rows, 1:3])
    t.hsl[rows, 0] = (t.hsl[rows, 0] + weight * hue_step) % 1.0
    t.extent[rows] += weight * (obs.extent - t.extent[rows])
    t.extent_slow[rows] += SLIDE_SMOOTHING * (obs.extent - t.extent_slow[rows])
    now, slow = obs.across, t.across_slow[rows]
    t.across[rows] = now
    t.depth[rows] = obs.depth
    t.across_slow[rows] = np.where(
        np.isnan(slow), now, np.where(np.isnan(now), slow, slow + SLIDE_SMOOTHING * (now - slow))
    )
    t.density[rows] += weight * (obs.density - t.density[rows])
    t.floor[rows] += weight * (obs.floor - t.floor[rows])  # a crown's cluster dipping to a hedge for a frame stays up
