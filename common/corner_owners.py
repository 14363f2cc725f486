"""Which piece of the world each followed corner is on: the lowest-numbered piece with a voxel
holding it (services/tracker/keypoint_motion.py's tracks, services/voxel_mapper/apart.py's parts),
for common/corner_motion.py's medians."""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from common.voxel_keys import bucket, pack

NDArray = npt.NDArray[Any]

#: most cells ``owners`` lays a dense grid over (1 MB of int32): the world-frame box around a
#: frame's clusters in the paper's volume at 0.25 m is 106,260 cells (229,000 turned 45 degrees);
#: at 0.1 m it can be 1.6 million, and those frames hash instead.
GRID_CELLS: int = 1 << 18


@numba.njit(cache=True)
def _probe(table: NDArray, shift: int, key: int) -> int:
    """The slot of ``key`` in an open-addressing table of keys (-1: free), or the free slot it would take."""
    mask = table.shape[0] - 1
    h = bucket(key, shift)
    while table[h] != -1 and table[h] != key:
        h = (h + 1) & mask
    return h


@numba.njit(cache=True)
def owners(
    voxels: NDArray, owner: NDArray, now: NDArray, n: NDArray, missed: NDArray, min_n: int, edge: float, pieces: int,
    grid: NDArray,
) -> tuple[NDArray, NDArray]:  # fmt: skip
    """Which piece (``owner`` of the voxel it lies in; of two, the lower; -1: none) each corner seen
    this frame with ``min_n`` positions or more is on, and how many each piece has.

    The pieces' voxels are written into a dense grid over their bounding box (``grid``, at least
    ``GRID_CELLS`` long, -1 throughout, and left so), and each corner reads its cell: with 50
    obstacles this took 62 µs a frame where an open-addressing table of the corners' voxels, which
    every cluster voxel looked its own up in, took 148 (``_chained``, still used where the box is
    too big for a grid).
    """
    big, small = np.iinfo(np.int64).max, np.iinfo(np.int64).min
    lo0 = lo1 = lo2 = big
    hi0 = hi1 = hi2 = small
    for v in range(voxels.shape[0]):
        if owner[v] >= 0:
            lo0, lo1, lo2 = min(lo0, voxels[v, 0]), min(lo1, voxels[v, 1]), min(lo2, voxels[v, 2])
            hi0, hi1, hi2 = max(hi0, voxels[v, 0]), max(hi1, voxels[v, 1]), max(hi2, voxels[v, 2])
    s0, s1, s2 = hi0 - lo0 + 1, hi1 - lo1 + 1, hi2 - lo2 + 1
    if lo0 > hi0 or s0 * s1 * s2 > grid.shape[0]:
        return _chained(voxels, owner, now, n, missed, min_n, edge, pieces)
    for v in range(voxels.shape[0]):
        o = owner[v]
        if o >= 0:
            g = ((voxels[v, 0] - lo0) * s1 + (voxels[v, 1] - lo1)) * s2 + (voxels[v, 2] - lo2)
            if grid[g] < 0 or o < grid[g]:
                grid[g] = o
    whose = np.full(now.shape[0], -1, np.int64)
    count = np.zeros(pieces, np.int64)
    for c in range(now.shape[0]):
        if n[c] < min_n or missed[c] != 0:
            continue
        f0, f1, f2 = np.floor(now[c, 0] / edge), np.floor(now[c, 1] / edge), np.floor(now[c, 2] / edge)
        # (compared as floats: a NaN position is in no cell)
        if lo0 <= f0 <= hi0 and lo1 <= f1 <= hi1 and lo2 <= f2 <= hi2:
            o = grid[((np.int64(f0) - lo0) * s1 + (np.int64(f1) - lo1)) * s2 + (np.int64(f2) - lo2)]
            if o >= 0:
                whose[c] = o
                count[o] += 1
    for v in range(voxels.shape[0]):
        if owner[v] >= 0:
            grid[((voxels[v, 0] - lo0) * s1 + (voxels[v, 1] - lo1)) * s2 + (voxels[v, 2] - lo2)] = -1
    return whose, count


@numba.njit(cache=True)
def _chained(
    voxels: NDArray, owner: NDArray, now: NDArray, n: NDArray, missed: NDArray, min_n: int, edge: float, pieces: int
) -> tuple[NDArray, NDArray]:
    """``owners`` for pieces spread too wide for a grid: the corners' voxels go into an
    open-addressing table, each voxel's corners chained, and every piece's voxel looks its own up
    once. Sorting the voxels' keys in numpy and searching them instead touched the frame's voxels
    three times over."""
    bits = 4
    while (1 << bits) < 2 * now.shape[0]:
        bits += 1
    size, shift = 1 << bits, 64 - bits
    table = np.full(size, -1, np.int64)
    head = np.empty(size, np.int64)  # the first corner in the slot's voxel
    chain = np.full(now.shape[0], -1, np.int64)  # the next corner in the same voxel
    for c in range(now.shape[0]):
        if n[c] >= min_n and missed[c] == 0:
            key = pack(
                np.int64(np.floor(now[c, 0] / edge)), np.int64(np.floor(now[c, 1] / edge)),
                np.int64(np.floor(now[c, 2] / edge)),
            )  # fmt: skip
            h = _probe(table, shift, key)
            if table[h] == -1:
                table[h], head[h] = key, -1
            chain[c], head[h] = head[h], c
    whose = np.full(now.shape[0], -1, np.int64)
    count = np.zeros(pieces, np.int64)
    for v in range(voxels.shape[0]):
        if owner[v] < 0:
            continue
        key = pack(voxels[v, 0], voxels[v, 1], voxels[v, 2])
        h = _probe(table, shift, key)
        c = head[h] if table[h] == key else -1
        while c >= 0:
            if whose[c] < 0 or owner[v] < whose[c]:
                if whose[c] >= 0:
                    count[whose[c]] -= 1
                whose[c] = owner[v]
                count[owner[v]] += 1
            c = chain[c]
    return whose, count
