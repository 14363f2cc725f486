"""The sparse voxel map of Sect. IV-A: only occupied voxels, hashed by integer coordinates.

A voxel's integer coordinates ``(i, j, k) = floor(p / edge)`` in the world frame are packed into
one int64 key (21 bits each), and an open-addressing hash table (linear probing, load <= 1/2)
maps keys to dense slots, so insert and lookup cost O(1) on average, and a move to any of the
26 neighbours is one key addition and one lookup. Per slot the map keeps running sums from which
the paper's per-voxel data follow: point count, centroid, mean and variance of RGB and of HSL.
With ``circular_hue`` each point's chroma vector is summed too (its direction is the hue, its
length how much colour the point has), so that the mean hue is an angle's mean and a grey's noise
cancels out (colour.py); the paper's reading, hue as a plain number, stays the default
(docs/results/voxel.md, "Session 36").

The frame-to-frame update follows the paper: points brought into the world with the vehicle pose
update the voxel they fall in, a voxel is created only where empty space becomes occupied, and
a voxel that received no point for more than ``keep_frames`` frames is removed (0 = the paper).
The per-point loop is numba-compiled: numpy would need an argsort of the keys (~20 ms for 300k
points) where a hash insert is ~10 ns per point.
"""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

from common.voxel_keys import OFFSET, bucket, pack, unpack
from services.voxel_mapper.colour import hue_and_spread, rgb_to_hsl

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

EMPTY = -1
INV255 = 1.0 / 255.0

# Columns of the per-voxel sums.
COUNT, XYZ, RGB, RGB2, HSL, HSL2 = 0, slice(1, 4), slice(4, 7), slice(7, 10), slice(10, 13), slice(13, 16)
HITS = 16  # points of the latest frame that hit the voxel
CHROMA = slice(17, 19)  # with circular hue: chroma vectors (r - (g + b) / 2, sqrt(3) / 2 (g - b))
CHROMA_W = 19  # ... and their lengths
N_STATS = 20
SQRT3_2 = float(np.sqrt(3.0) / 2.0)


@numba.njit(cache=True)
def find(table_keys: I64, table_slots: npt.NDArray[np.int32], shift: int, key: int) -> int:
    """Slot of a key, or EMPTY."""
    mask = table_keys.shape[0] - 1
    h = bucket(key, shift)
    while True:
        s = table_slots[h]
        if s == EMPTY or table_keys[h] == key:
            return s
        h = (h + 1) & mask


@numba.njit(cache=True)
def _slots_at(points: F64, edge: float, table_keys: I64, table_slots: npt.NDArray[np.int32], shift: int) -> I64:
    """The slot of the voxel each world point lies in, or EMPTY."""
    out = np.full(points.shape[0], EMPTY, np.int64)
    for p in range(points.shape[0]):
        fi, fj, fk = np.floor(points[p, 0] / edge), np.floor(points[p, 1] / edge), np.floor(points[p, 2] / edge)
        if abs(fi) < OFFSET and abs(fj) < OFFSET and abs(fk) < OFFSET:  # not NaN, not off the keys
            out[p] = find(table_keys, table_slots, shift, pack(np.int64(fi), np.int64(fj), np.int64(fk)))
    return out


@numba.njit(cache=True)
def _rebuild(keys: I64, n: int, table_keys: I64, table_slots: npt.NDArray[np.int32], shift: int) -> None:
    table_slots[:] = EMPTY
    mask = table_keys.shape[0] - 1
    for s in range(n):
        h = bucket(keys[s], shift)
        while table_slots[h] != EMPTY:
            h = (h + 1) & mask
        table_keys[h] = keys[s]
        table_slots[h] = s


@numba.njit(cache=True, inline="always")
def _probe_or_add(key: int, n: int, limit: int, keys: I64, stats: F64, table_keys: I64,
                  table_slots: npt.NDArray[np.int32], shift: int) -> int:
    """Slot of ``key``; a new voxel gets slot ``n``; -1 when the map must grow first."""
    mask = table_keys.shape[0] - 1
    h = bucket(key, shift)
    while True:
        s = table_slots[h]
        if s == EMPTY:
            if n >= limit:
                return -1
            table_slots[h] = n
            table_keys[h] = key
            keys[n] = key
            stats[n, :] = 0.0
            return n
        if table_keys[h] == key:
            return s
        h = (h + 1) & mask


@numba.njit(cache=True)
def _insert(points: npt.NDArray[np.float32], colors: npt.NDArray[np.uint8], rot: F64, trans: F64,
            inv_edge: float, start: int, n: int, keys: I64, stats: F64, last_seen: I64, frame: int,
            table_keys: I64, table_slots: npt.NDArray[np.int32], shift: int, circular_hue: bool) -> tuple[int, int]:
    """Add points[start:] to the map; stops early (returning where) when the table is half full."""
    limit = min(keys.shape[0], table_keys.shape[0] // 2)
    last_key, last_slot = -1, -1
    for p in range(start, points.shape[0]):
        x, y, z = np.float64(points[p, 0]), np.float64(points[p, 1]), np.float64(points[p, 2])
        wx = rot[0, 0] * x + rot[0, 1] * y + rot[0, 2] * z + trans[0]
        wy = rot[1, 0] * x + rot[1, 1] * y + rot[1, 2] * z + trans[1]
        wz = rot[2, 0] * x + rot[2, 1] * y + rot[2, 2] * z + trans[2]
        fi, fj, fk = np.floor(wx * inv_edge), np.floor(wy * inv_edge), np.floor(wz * inv_edge)
        if not (abs(fi) < OFFSET and abs(fj) < OFFSET and abs(fk) < OFFSET):
            continue  # NaN or beyond +-2^20 voxels from the world origin
        key = pack(np.int64(fi), np.int64(fj), np.int64(fk))
        if key == last_key:  # neighbouring pixels often share a voxel: skip the probe
            s = last_slot
        else:
            s = _probe_or_add(key, n, limit, keys, stats, table_keys, table_slots, shift)
            if s < 0:
                return n, p
            if s == n:
                n += 1
            last_key, last_slot = key, s
        r, g, b = colors[p, 0] * INV255, colors[p, 1] * INV255, colors[p, 2] * INV255
        hue, sat, light = rgb_to_hsl(r, g, b)
        st = stats[s]
        st[0] += 1.0
        st[1] += wx
        st[2] += wy
        st[3] += wz
        st[4] += r
        st[5] += g
        st[6] += b
        st[7] += r * r
        st[8] += g * g
        st[9] += b * b
        st[10] += hue
        st[11] += sat
        st[12] += light
        st[13] += hue * hue
        st[14] += sat * sat
        st[15] += light * light
        if circular_hue:  # the chroma plane's coordinates: no trigonometry per point
            alpha, beta = r - 0.5 * (g + b), SQRT3_2 * (g - b)
            st[17] += alpha
            st[18] += beta
            st[19] += np.sqrt(alpha * alpha + beta * beta)
        if last_seen[s] != frame:
            st[16] = 0.0
            last_seen[s] = frame
        st[16] += 1.0
    return n, points.shape[0]


class VoxelMap:
    """Occupied voxels of the world at one edge length, with their running statistics."""

    def __init__(self, edge: float, keep_frames: int = 0, capacity: int = 1 << 15, circular_hue: bool = False) -> None:
        self.edge = float(edge)
        self.keep_frames = int(keep_frames)
        self.circular_hue = bool(circular_hue)
        self.frame = 0
        self.n = 0
        self._allocate(capacity)

    def _allocate(self, capacity: int) -> None:
        bits = max(4, int(np.ceil(np.log2(2 * capacity))))
        self.keys = np.zeros(capacity, dtype=np.int64)
        self.stats = np.zeros((capacity, N_STATS), dtype=np.float64)
        self.last_seen = np.zeros(capacity, dtype=np.int64)
        self.table_keys = np.zeros(1 << bits, dtype=np.int64)
        self.table_slots = np.full(1 << bits, EMPTY, dtype=np.int32)
        self.shift = 64 - bits

    def _grow(self) -> None:
        keys, stats, seen, n = self.keys, self.stats, self.last_seen, self.n
        self._allocate(2 * keys.shape[0])
        self.keys[:n], self.stats[:n], self.last_seen[:n] = keys[:n], stats[:n], seen[:n]
        _rebuild(self.keys, n, self.table_keys, self.table_slots, self.shift)

    def clear(self) -> None:
        """Forget every voxel (a new world epoch)."""
        self.n = 0
        self.table_slots[:] = EMPTY

    def integrate(self, points: npt.NDArray[np.float32], colors: npt.NDArray[np.uint8], pose: F64) -> None:
        """Bring vehicle-frame points into the world with ``pose`` and add them to their voxels."""
        self.frame += 1
        pts = np.ascontiguousarray(points, dtype=np.float32)
        cols = np.ascontiguousarray(colors, dtype=np.uint8)
        rot = np.ascontiguousarray(pose[:3, :3], dtype=np.float64)
        trans = np.ascontiguousarray(pose[:3, 3], dtype=np.float64)
        start = 0
        while start < pts.shape[0]:
            self.n, start = _insert(pts, cols, rot, trans, 1.0 / self.edge, start, self.n, self.keys, self.stats,
                                    self.last_seen, self.frame, self.table_keys, self.table_slots, self.shift,
                                    self.circular_hue)
            if start < pts.shape[0]:
                self._grow()

    def forget_unseen(self) -> int:
        """Remove voxels without a point for more than ``keep_frames`` frames; returns how many."""
        keep = self.frame - self.last_seen[: self.n] <= self.keep_frames
        removed = int(self.n - np.count_nonzero(keep))
        if removed:
            self.retain(keep)
        return removed

    def retain(self, keep: npt.NDArray[np.bool_]) -> None:
        """Keep only the slots where ``keep`` is true, and rehash."""
        n = int(np.count_nonzero(keep))
        self.keys[:n] = self.keys[: self.n][keep]
        self.stats[:n] = self.stats[: self.n][keep]
        self.last_seen[:n] = self.last_seen[: self.n][keep]
        self.n = n
        _rebuild(self.keys, n, self.table_keys, self.table_slots, self.shift)

    def slot_of(self, coords: npt.ArrayLike) -> int:
        """Slot of the voxel at integer coordinates (i, j, k), or -1 where it is empty."""
        i, j, k = (int(c) for c in coords)
        return int(find(self.table_keys, self.table_slots, self.shift, pack(i, j, k)))

    def slots_at(self, points: F64) -> I64:
        """The slot of the voxel each world point (Nx3) lies in, ``floor(p / edge)`` as the tracker
        places them, or -1 where that voxel is empty."""
        pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        return _slots_at(pts, self.edge, self.table_keys, self.table_slots, self.shift)

    # ---- per-voxel data of the first ``n`` slots

    @property
    def coords(self) -> npt.NDArray[np.int32]:
        return unpack(self.keys[: self.n])

    @property
    def counts(self) -> F64:
        return self.stats[: self.n, COUNT]

    @property
    def hits(self) -> F64:
        """Points of the latest frame per voxel (0 for a voxel only kept by the decay)."""
        return np.where(self.last_seen[: self.n] == self.frame, self.stats[: self.n, HITS], 0.0)

    @property
    def centroids(self) -> F64:
        return self.stats[: self.n, XYZ] / self.counts[:, None]

    def mean(self, space: str) -> F64:
        """Mean colour per voxel, ``space`` = "rgb" or "hsl" (0..1)."""
        return colour_stats(self.stats[: self.n], space, self.circular_hue)[0]

    def variance(self, space: str) -> F64:
        """Colour variance per voxel; for hue the circular variance (hue_and_spread)."""
        return colour_stats(self.stats[: self.n], space, self.circular_hue)[1]


def colour_stats(sums: F64, space: str, circular_hue: bool = False) -> tuple[F64, F64]:
    """Mean and variance of colour from rows of the per-voxel sums (one voxel's, or a cluster's added up).

    With ``circular_hue`` the hue's are the chroma vectors' direction and circular variance.
    """
    n = sums[:, COUNT : COUNT + 1]
    cols, sq = (RGB, RGB2) if space == "rgb" else (HSL, HSL2)
    mean = sums[:, cols] / n
    var = np.maximum(sums[:, sq] / n - mean * mean, 0.0)
    if space == "hsl" and circular_hue:
        mean[:, 0], var[:, 0] = hue_and_spread(sums[:, CHROMA], sums[:, CHROMA_W])
    return mean, var
