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
(in two, hanging's held-out TP fell 78.1 -> 75.2 %). A cluster a moving track took is no standing
object: a walker following another steps where the first was.

With ``frames`` 3 (tracker replays, docs/results/tracking.md, "Session 34"): KITTI tracking 0001's
false moving frames 3 -> 0, held-out FP lower on every scenario (urban 3.4 -> 2.7 %, hanging 4.1
-> 2.8 %, slope 3.0 -> 2.0 %), overtake, hanging and slope TP up a point, urban and crossing TP
down half a point; the tuning seeds' crossing TP 65.5 -> 62.1 % (a walker leaving the one he
waited beside). Only the clusters whose boxes reach an old footprint's are looked at voxel by
voxel, in a compiled pass over a small grid: the tracker takes 1.09 times as long per frame with
50 obstacles (`python -m services.tracker.benchmark --against 593db69`).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from common.messages import Cluster
from services.tracker import motion_window
from services.tracker.observations import Observations
from services.tracker.track import TrackTable

NDArray = npt.NDArray[Any]


@numba.njit(cache=True)
def _held_shares(
    old: NDArray, old_start: NDArray, theirs: NDArray, their_start: NDArray, slot: NDArray, cell: int
) -> NDArray:
    """Per checked track, the share of its old footprint's cells that its pairs' voxels fall in.

    ``old`` holds the tracks' old voxels one after the other (``old_start`` offsets), ``theirs``
    the paired clusters' (``their_start``), ``slot`` each pair's track. Each footprint is marked
    on a small dense grid over its own box: the work is one pass over the voxels.
    """
    n = len(old_start) - 1
    out = np.zeros(n)
    pair = 0
    for k in range(n):
        a, b = old_start[k], old_start[k + 1]
        if a == b:
            while pair < len(slot) and slot[pair] == k:
                pair += 1
            continue
        lo = np.empty(3, np.int64)
        hi = np.empty(3, np.int64)
        for d in range(3):
            lo[d] = old[a, d] // cell
            hi[d] = lo[d]
        for i in range(a, b):
            for d in range(3):
                c = old[i, d] // cell
                lo[d] = min(lo[d], c)
                hi[d] = max(hi[d], c)
        grid = np.zeros((hi[0] - lo[0] + 1, hi[1] - lo[1] + 1, hi[2] - lo[2] + 1), np.int8)
        for i in range(a, b):
            grid[old[i, 0] // cell - lo[0], old[i, 1] // cell - lo[1], old[i, 2] // cell - lo[2]] = 1
        cells = 0
        for v in grid.ravel():
            cells += v
        held = 0
        while pair < len(slot) and slot[pair] == k:
            for i in range(their_start[pair], their_start[pair + 1]):
                x = theirs[i, 0] // cell - lo[0]
                y = theirs[i, 1] // cell - lo[1]
                z = theirs[i, 2] // cell - lo[2]
                if 0 <= x < grid.shape[0] and 0 <= y < grid.shape[1] and 0 <= z < grid.shape[2] and grid[x, y, z] == 1:
                    grid[x, y, z] = 2
                    held += 1
            pair += 1
        out[k] = held / cells
    return out


@dataclass(frozen=True)
class _Seen:
    """One frame's sightings: which tracks took which clusters, and those clusters."""

    ids: NDArray  # (m,) track ids, sorted
    voxels: list[NDArray]  # (m,) the voxels of the cluster each took
    lo: NDArray  # (m, 3) its box
    hi: NDArray


@dataclass
class LeftBehind:
    """The last frames' sightings; which tracks left their footprint to others (config: ``tracker.left_behind_*``)."""

    frames: int  # compare with the footprint this many frames back (trusted ones); 0 = off
    share: float = 0.5  # more of the old footprint than this held by other clusters: the track slid
    cell: int = 2  # grid cell side in voxels
    _seen: deque[_Seen] = field(default_factory=deque)

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
        ``frames`` frames back, if they were seen then, another cluster holds now.

        ``obs`` are the clusters (``pieces``) the tracks were paired with, ``moving`` the tracks'
        labels by row: a cluster a moving track took is no standing object (a walker following
        another steps where the first was). Only the clusters whose boxes reach an old footprint's
        box (grown by a cell of voxels of ``edge`` m) are looked at voxel by voxel.
        """
        if self.frames <= 0:
            return rows[:0]
        index = obs.index.tolist()
        order = np.argsort(ids[rows], kind="stable")
        seen = _Seen(
            ids[rows][order],
            [pieces[index[c]].voxels for c in cols[order].tolist()],
            obs.bbox_min[cols[order]],
            obs.bbox_max[cols[order]],
        )
        self._seen.append(seen)
        if len(self._seen) <= self.frames:
            return rows[:0]
        then = self._seen.popleft()
        at = np.minimum(np.searchsorted(then.ids, ids[rows]), max(len(then.ids) - 1, 0))
        found = np.flatnonzero((then.ids[at] == ids[rows]) if len(then.ids) else np.zeros(len(rows), dtype=bool))
        if len(found) == 0:
            return rows[:0]
        past = at[found]
        standing = np.ones(len(index), dtype=bool)
        standing[cols[moving[rows]]] = False
        grow = self.cell * edge
        # boxes overlapping in x and y (a superset of those holding a cell of the footprint)
        lo, hi = obs.bbox_min, obs.bbox_max
        then_lo, then_hi = then.lo[past] - grow, then.hi[past] + grow
        near = standing[None] & (lo[None, :, 0] <= then_hi[:, None, 0]) & (hi[None, :, 0] >= then_lo[:, None, 0])
        near &= (lo[None, :, 1] <= then_hi[:, None, 1]) & (hi[None, :, 1] >= then_lo[:, None, 1])
        near[np.arange(len(found)), cols[found]] = False
        pairs = np.argwhere(near)  # (checked track, cluster) pairs to look at voxel by voxel
        if len(pairs) == 0:
            return rows[:0]
        checked = np.unique(pairs[:, 0])
        olds = [np.asarray(then.voxels[past[j]], dtype=np.int64).reshape(-1, 3) for j in checked.tolist()]
        theirs = [np.asarray(pieces[index[q]].voxels, dtype=np.int64).reshape(-1, 3) for q in pairs[:, 1].tolist()]
        old_start = np.cumsum([0] + [len(o) for o in olds])
        their_start = np.cumsum([0] + [len(t) for t in theirs])
        slot = np.searchsorted(checked, pairs[:, 0])  # each pair's checked track, 0..len(checked)
        held = _held_shares(np.concatenate(olds), old_start, np.concatenate(theirs), their_start, slot, self.cell)
        share = np.zeros(len(found))
        share[checked] = held
        return rows[found[share > self.share]]


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
