"""A moving object takes its voxels with it; a track that left a standing one behind slid off it.

The paper's map keeps a voxel only while points fall in it, so where a moving object stood a few
frames ago is empty now, or its own cluster still covers it (a long car moving slowly). A track
whose old footprint is now held by another cluster has moved on while what it followed stood
still: it hopped from piece to piece along a row of far clutter, and each hop within the range
noise passed for motion. On KITTI tracking 0001, with the small pieces added up
(``voxel.aggregate_in_turn_m``), tracks slid like that along a low wall 35-45 m ahead at 7-8 m/s
for ten frames and more, the faces' window agreeing, since each hop went the same way (the
velocity it had learnt led the prediction, and so the association, onto the next piece ahead).
Measured first with the tracks' boxes on the held-out synthetic runs (seeds 7-10): of 1,102
frames of a moving object correctly called moving, one had more than half of its box four frames
back held by another cluster; of KITTI's 37 false moving frames, 14 had.

Such a track's velocity is the slide's: it starts again from rest with a new track's doubt, and
its faces' window starts again. Footprints are compared on a grid of ``cell`` voxels, so the
range jitter of a far object's voxels does not hide that it is still there, and in three
dimensions: a car driving under a gantry leaves its footprint on the road, not under the beam
(in two, hanging's held-out TP fell 78.1 -> 75.2 %). A piece a moving track took is no standing
object: a walker following another steps where the first was.

With ``frames`` 3 (tracker replays, docs/results/tracking.md, "Session 34"): KITTI tracking 0001's
false moving frames 3 -> 0, held-out FP lower on every scenario (urban 3.4 -> 2.7 %, hanging 4.1
-> 2.8 %, slope 3.0 -> 2.0 %), overtake and hanging TP up a point, urban and crossing TP down half
a point, but the tuning seeds' crossing TP 65.5 -> 61.5 %, and the tracker 1.33 times slower per
frame with 50 obstacles (session 31's 1.55 ms would be about 2.1, over the 2 ms goal). Off by
default until it is cheaper.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from common.messages import Cluster
from services.tracker import motion_window
from services.tracker.observations import Observations
from services.tracker.track import TrackTable

NDArray = npt.NDArray[Any]

#: grid cell indices are packed in one int64, 21 bits an axis, offset to stay positive
_BITS, _OFFSET = 21, 1 << 20


def cells(voxels: NDArray, cell: int) -> NDArray:
    """The key of the grid cell each voxel (n, 3) falls in."""
    c = np.floor_divide(np.asarray(voxels, dtype=np.int64).reshape(-1, 3), cell) + _OFFSET
    return (c[:, 0] << (2 * _BITS)) | (c[:, 1] << _BITS) | c[:, 2]


@dataclass
class LeftBehind:
    """Each track's last footprints, and which tracks left theirs to others (config: ``tracker.left_behind_*``)."""

    frames: int  # compare with the footprint this many observations back; 0 = off
    share: float = 0.5  # more of the old footprint than this held by other clusters: the track slid
    cell: int = 2  # grid cell side in voxels
    _history: dict[int, deque[tuple[NDArray, NDArray, NDArray]]] = field(default_factory=dict)  # voxels, box

    def slid(
        self,
        ids: NDArray,
        rows: NDArray,
        cols: NDArray,
        obs: Observations,
        pieces: list[Cluster],
        moving: NDArray,
        edge: float,
    ) -> NDArray:
        """The ``rows`` (tracks seen this frame, each paired with cluster ``cols``) whose footprint
        ``frames`` sightings back another cluster holds now.

        ``obs`` are the clusters (``pieces``) the tracks were paired with, ``moving`` the tracks'
        labels by row: a cluster a moving track took is no standing object (a walker following
        another steps where the first was). Every seen track's footprint is remembered for later
        frames; tracks gone are forgotten. Only the clusters whose boxes reach an old footprint's
        box (grown by a cell of voxels of ``edge`` m) are looked at voxel by voxel.
        """
        if self.frames <= 0:
            return rows[:0]
        alive = set(ids.tolist())
        for gone in [i for i in self._history if i not in alive]:
            del self._history[gone]
        index, lo, hi = obs.index.tolist(), obs.bbox_min, obs.bbox_max
        checked, old = [], []
        for k, (track, col) in enumerate(zip(ids[rows].tolist(), cols.tolist(), strict=True)):
            past = self._history.get(track)
            if past is None:
                past = self._history[track] = deque(maxlen=self.frames)
            elif len(past) == self.frames and len(past[0][0]):
                checked.append(k)
                old.append(past[0])
            past.append((pieces[index[col]].voxels, lo[col], hi[col]))
        if not checked:
            return rows[:0]
        standing = np.ones(len(index), dtype=bool)
        standing[cols[moving[rows]]] = False
        grow = self.cell * edge
        old_lo = np.array([o[1] for o in old])[:, None] - grow
        old_hi = np.array([o[2] for o in old])[:, None] + grow
        near = ((lo[None] <= old_hi) & (hi[None] >= old_lo)).all(axis=2) & standing[None]
        near[np.arange(len(checked)), cols[checked]] = False
        out = []
        for j in np.flatnonzero(near.any(axis=1)):
            theirs = np.concatenate([cells(pieces[index[q]].voxels, self.cell) for q in np.flatnonzero(near[j])])
            if np.isin(np.unique(cells(old[j][0], self.cell)), theirs).mean() > self.share:
                out.append(rows[checked[j]])
        return np.asarray(out, dtype=rows.dtype)


def restart_from_rest(t: TrackTable, rows: NDArray, velocity_var: NDArray) -> int:
    """The tracks ``rows`` start again from rest, with a new track's velocity variance; how many."""
    if len(rows) == 0:
        return 0
    t.x[rows, 3:5] = 0.0
    t.p[rows, 3:5, :] = 0.0
    t.p[rows, :, 3:5] = 0.0
    t.p[rows, 3, 3], t.p[rows, 4, 4] = velocity_var[0], velocity_var[1]
    t.moving[rows] = False
    motion_window.restart(t.window_n, rows)
    return len(rows)
