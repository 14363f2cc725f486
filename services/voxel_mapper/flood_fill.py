"""Colour flood fill over the 26-neighbourhood (Algorithm IV-B.1 with Eq. 1).

A cluster grows from a seed voxel through the closed Chebyshev unit ball of each member: a
not-yet-considered neighbour joins when its mean colour is within ``epsilon`` (Eq. 1) of the
cluster's running mean colour (the mean of its voxels' mean colours; with circular hue, the
hue is the direction of their summed chroma vectors, colour.py). The growth is sequential
(each decision depends on the mean so far), so it is a numba kernel; neighbours are found in the
map's hash table, one key addition and one lookup each. Seeds are taken in order of decreasing
point count, so a cluster's running mean starts from its best-observed voxel.
"""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

from common.voxel_keys import BITS
from services.voxel_mapper.colour import hue_of, similarity
from services.voxel_mapper.voxel_map import CHROMA, EMPTY, VoxelMap, find

I32 = npt.NDArray[np.int32]


def neighbour_deltas(reach: int = 1) -> npt.NDArray[np.int64]:
    """Key offsets of the voxels up to ``reach`` along each axis but the centre: the 26 neighbours at 1."""
    span = range(-reach, reach + 1)
    steps = [(i, j, k) for i in span for j in span for k in span if (i, j, k) != (0, 0, 0)]
    return np.array([(i << (2 * BITS)) + (j << BITS) + k for i, j, k in steps], dtype=np.int64)


DELTAS = neighbour_deltas()


@numba.njit(cache=True)
def _grow(seeds: npt.NDArray[np.int64], candidate: npt.NDArray[np.bool_], keys: npt.NDArray[np.int64],
          table_keys: npt.NDArray[np.int64], table_slots: I32, shift: int, deltas: npt.NDArray[np.int64],
          rgb: npt.NDArray[np.float64], hsl: npt.NDArray[np.float64], chroma: npt.NDArray[np.float64],
          circular: bool, epsilon: float) -> tuple[I32, int]:
    labels = np.full(candidate.shape[0], -1, dtype=np.int32)
    queue = np.empty(seeds.shape[0], dtype=np.int64)
    sum_rgb = np.zeros(3)
    sum_hsl = np.zeros(3)
    sum_chroma = np.zeros(2)
    mean_rgb = np.zeros(3)
    mean_hsl = np.zeros(3)
    n_clusters = 0
    for seed in seeds:
        if labels[seed] != -1:
            continue
        label = n_clusters
        n_clusters += 1
        labels[seed] = label
        sum_rgb[:] = rgb[seed]
        sum_hsl[:] = hsl[seed]
        sum_chroma[:] = chroma[seed]
        members = 1.0
        mean_rgb[:] = rgb[seed]
        mean_hsl[:] = hsl[seed]
        queue[0] = seed
        head, tail = 0, 1
        while head < tail:
            key = keys[queue[head]]
            head += 1
            for d in deltas:
                s = find(table_keys, table_slots, shift, key + d)
                if s == EMPTY or not candidate[s] or labels[s] != -1:
                    continue
                if similarity(rgb[s], hsl[s], mean_rgb, mean_hsl, circular) < epsilon:
                    labels[s] = label
                    sum_rgb += rgb[s]
                    sum_hsl += hsl[s]
                    sum_chroma += chroma[s]
                    members += 1.0
                    for c in range(3):
                        mean_rgb[c] = sum_rgb[c] / members
                        mean_hsl[c] = sum_hsl[c] / members
                    if circular:
                        mean_hsl[0] = hue_of(sum_chroma[0], sum_chroma[1])
                    queue[tail] = s
                    tail += 1
    return labels, n_clusters


@numba.njit(cache=True)
def _contacts(members: npt.NDArray[np.int64], labels: I32, keys: npt.NDArray[np.int64],
              table_keys: npt.NDArray[np.int64], table_slots: I32, shift: int,
              deltas: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    out = np.empty((members.shape[0] * deltas.shape[0], 2), dtype=np.int64)
    n = 0
    for v in members:
        a = labels[v]
        for d in deltas:
            s = find(table_keys, table_slots, shift, keys[v] + d)
            if s != EMPTY and labels[s] > a:
                out[n, 0] = a
                out[n, 1] = labels[s]
                n += 1
    return out[:n]


def flood_fill(vmap: VoxelMap, candidate: npt.NDArray[np.bool_], epsilon: float) -> tuple[I32, int]:
    """Cluster label per map slot (-1 = not a candidate) and the number of clusters."""
    members = np.flatnonzero(candidate)
    seeds = members[np.argsort(-vmap.counts[members], kind="stable")]
    rgb = np.ascontiguousarray(vmap.mean("rgb"))
    hsl = np.ascontiguousarray(vmap.mean("hsl"))
    chroma = np.ascontiguousarray(vmap.stats[: vmap.n, CHROMA] / vmap.counts[:, None])
    return _grow(seeds, candidate, vmap.keys, vmap.table_keys, vmap.table_slots, vmap.shift, DELTAS,
                 rgb, hsl, chroma, vmap.circular_hue, float(epsilon))


def touching_pairs(vmap: VoxelMap, labels: I32, deltas: npt.NDArray[np.int64] = DELTAS) -> npt.NDArray[np.int64]:
    """Distinct pairs (a, b), a < b, of clusters with 26-neighbouring voxels (or voxels ``deltas`` apart)."""
    members = np.flatnonzero(labels >= 0)
    pairs = _contacts(members, labels, vmap.keys, vmap.table_keys, vmap.table_slots, vmap.shift, deltas)
    if pairs.shape[0] == 0:
        return pairs
    packed = np.sort(pairs[:, 0] << 32 | pairs[:, 1])
    packed = packed[np.concatenate(([True], np.diff(packed) != 0))]
    return np.stack([packed >> 32, packed & 0xFFFFFFFF], axis=1)
