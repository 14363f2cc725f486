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
    _history: dict[int, deque[NDArray]] = field(default_factory=dict)

    def slid(
        self, ids: NDArray, rows: NDArray, piece_of: dict[int, Cluster], pieces: list[Cluster], moving: NDArray
    ) -> NDArray:
        """The rows (of ``rows``, the tracks seen this frame) whose footprint ``frames`` back another piece holds now.

        ``piece_of`` maps a track row to the piece it took, ``pieces`` are all of this frame's,
        ``moving`` the tracks' labels (by row): a piece a moving track took is no standing object
        (a walker following another steps where the first was). Every seen track's footprint is
        remembered for later frames; tracks gone are forgotten.
        """
        if self.frames <= 0:
            return rows[:0]
        alive = {int(i) for i in ids}
        for gone in [i for i in self._history if i not in alive]:
            del self._history[gone]
        if len(rows) == 0:
            return rows
        index = {id(p): k for k, p in enumerate(pieces)}
        own = np.array([index[id(piece_of[int(r)])] for r in rows], dtype=np.int64)
        # every cell a standing piece holds, sorted by cell and then by piece
        walking = np.zeros(len(pieces), dtype=bool)
        walking[own[moving[rows]]] = True
        sizes = np.array([len(p.voxels) for p in pieces], dtype=np.int64)
        owner = np.repeat(np.arange(len(pieces)), sizes)
        voxels = np.concatenate([np.asarray(p.voxels).reshape(-1, 3) for p in pieces]) if pieces else np.zeros((0, 3))
        standing = ~walking[owner]
        key, holder = cells(voxels[standing], self.cell), owner[standing]
        order = np.lexsort((holder, key))
        key, holder = key[order], holder[order]
        # each checked track's footprint ``frames`` sightings back, one entry per cell
        checked, old = [], []
        for k, row in enumerate(rows):
            past = self._history.setdefault(int(ids[row]), deque(maxlen=self.frames))
            if len(past) == self.frames and len(past[0]):
                checked.append(k)
                old.append(past[0])
            past.append(np.asarray(piece_of[int(row)].voxels).reshape(-1, 3))
        if not checked or len(key) == 0:
            return rows[:0]
        track = np.repeat(np.arange(len(checked)), [len(o) for o in old])
        cell = cells(np.concatenate(old), self.cell)
        first = np.lexsort((cell, track))
        track, cell = track[first], cell[first]
        unique = np.ones(len(cell), dtype=bool)
        unique[1:] = (cell[1:] != cell[:-1]) | (track[1:] != track[:-1])
        track, cell = track[unique], cell[unique]
        # a cell counts if a standing piece but the track's own holds it: within the cell's
        # entries (sorted by piece) the first or the last is another piece
        lo, hi = np.searchsorted(key, cell, "left"), np.searchsorted(key, cell, "right")
        mine = own[np.asarray(checked)][track]
        held = (hi > lo) & ((holder[np.minimum(lo, len(key) - 1)] != mine) | (holder[np.maximum(hi - 1, 0)] != mine))
        share = np.bincount(track, held, minlength=len(checked)) / np.bincount(track, minlength=len(checked))
        return rows[np.asarray(checked)[share > self.share]]


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
