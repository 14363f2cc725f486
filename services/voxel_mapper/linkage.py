"""Clusters that are parts of one object: strongly linked neighbours are joined before Alg. IV-B.2.

Colour flood fill splits an object wherever its colour changes (a car's paint and its glass, a
walker's coat and trousers), and the voxel grid splits it wherever stereo sees no surface between
two faces: the top of a car's boot seen from 20 m spans less than a pixel row, so the back of the
boot and the rear window end up three voxels apart along the line of sight. Both are measured
on the synthetic urban scenario with true disparity (one cluster for only 47 % of objects at
epsilon 0.35). Two clusters of at least ``min_voxels`` each are joined here when the share of
one's voxels linked to the other reaches ``min_share``: a voxel is linked to a cluster that owns
one of its 26 neighbours, or the first voxel seen behind an empty gap up to ``bridge_voxels``
long along the horizontal line of sight (the gap a grazing surface leaves). Separate objects
touch in a few voxels only; parts of one object share a whole edge or face. The paper's own
aggregation of small clusters follows.

The grazing surface need not lie within one layer of voxels: a bonnet or a boot lid seen edge-on
leaves the part below it and the part above it apart in range with no layer holding both. So a
voxel with nothing above it also looks one layer up, along the line of sight away from the camera,
for up to ``climb`` voxels past its neighbours, and a voxel with nothing below it looks one layer
down, towards the camera. Such a step link must be seen from both parts (a low box's top also
looks up into a hedge behind it, but the hedge stands on the road and has no bottom in the air to
look back from). ``voxel.step_bridge_voxels`` 4 (1 m): on synthetic urban, crossing and overtake
seeds 1-2 objects in one cluster rose by 0 to 3.6 points with moving TP and FP unchanged; 2 gained
0.5 at most, and 8 cost crossing seed 2 five points of moving TP (docs/results/voxel.md).

Since session 53 a learned model judges the linked pairs too (``voxel.join_model``, join_model.py,
part_pairs.py): the rule's join stands unless the model gives it under ``voxel.join_veto`` (0.5),
and a linked pair it gives over ``voxel.join_probability`` (0.8) is joined whatever the share. The
flood fill's parts are nearly pure; which are joined is what cost walkers their clusters (joined by
the ground truth, held-out urban has 90 % of its objects in one cluster against 80 %).

``min_voxels`` here (``voxel.join_min_voxels``, 6) is below the noise limit on purpose: a walker
seen from the front is 15-30 voxels split by colour into coat and trousers of 6-15 each, and
with the noise limit (20) gating the join too, both parts were aggregated into a facade or dropped
in alternate frames (synthetic crossing, seed 7: objects in one cluster 55 -> 40 % when the limit
went from 12 to 20; 62 % with parts joined from 8 voxels, docs/results/voxel.md). 8 until session
46: with ramp pixels snapped, 6 added true moving frames on all three sets of seeds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import numpy.typing as npt

from common.voxel_keys import BITS, FIELD, OFFSET
from services.voxel_mapper.apart import Apart
from services.voxel_mapper.flood_fill import DELTAS
from services.voxel_mapper.join_model import JoinModel
from services.voxel_mapper.part_pairs import LinkCounts, pair_features
from services.voxel_mapper.voxel_map import EMPTY, VoxelMap, find, pack

I32 = npt.NDArray[np.int32]
MAX_SEEN = 32
NO_DELTAS = np.zeros(0, dtype=np.int64)  # for a pass of step links alone


@numba.njit(cache=True)
def _remember(seen: npt.NDArray[np.int64], n_seen: int, b: int) -> int:
    """Add cluster ``b`` to the first ``n_seen`` of ``seen`` unless there; the new count."""
    for q in range(n_seen):
        if seen[q] == b:
            return n_seen
    if n_seen < MAX_SEEN:
        seen[n_seen] = b
        return n_seen + 1
    return n_seen


@numba.njit(cache=True)
def _links(members: npt.NDArray[np.int64], labels: I32, keys: npt.NDArray[np.int64],
           table_keys: npt.NDArray[np.int64], table_slots: I32, shift: int, deltas: npt.NDArray[np.int64],
           sight: npt.NDArray[np.float64], bridge: int, climb: int) -> npt.NDArray[np.int64]:
    """(a, b) once for every voxel of cluster a linked to a different cluster b."""
    out = np.empty((members.shape[0] * 4, 2), dtype=np.int64)
    seen = np.empty(MAX_SEEN, dtype=np.int64)
    n = 0
    for m in range(members.shape[0]):
        v = members[m]
        a = labels[v]
        key = keys[v]
        n_seen = 0
        gap = True  # the line of sight crosses only empty voxels so far
        for step in range(deltas.shape[0] + bridge):
            if step < deltas.shape[0]:
                s = find(table_keys, table_slots, shift, key + deltas[step])
            else:
                far = step - deltas.shape[0] + 1  # 1 .. bridge voxels along the line of sight
                i = (key >> (2 * BITS)) - OFFSET + int(np.floor(0.5 + far * sight[m, 0]))
                j = ((key >> BITS) & FIELD) - OFFSET + int(np.floor(0.5 + far * sight[m, 1]))
                s = find(table_keys, table_slots, shift, pack(i, j, (key & FIELD) - OFFSET))
                if not gap or (far == 1 and s != EMPTY):
                    break  # something seen right behind: no gap to bridge
                gap = s == EMPTY
            if s == EMPTY or labels[s] < 0 or labels[s] == a:
                continue
            n_seen = _remember(seen, n_seen, labels[s])
        if climb > 0:
            i0 = (key >> (2 * BITS)) - OFFSET
            j0 = ((key >> BITS) & FIELD) - OFFSET
            k0 = (key & FIELD) - OFFSET
            for dz in (1, -1):  # a top voxel looks one layer up and away, a bottom one down and back
                if find(table_keys, table_slots, shift, pack(i0, j0, k0 + dz)) != EMPTY:
                    continue
                for far in range(1, climb + 2):
                    i = i0 + int(np.floor(0.5 + dz * far * sight[m, 0]))
                    j = j0 + int(np.floor(0.5 + dz * far * sight[m, 1]))
                    s = find(table_keys, table_slots, shift, pack(i, j, k0 + dz))
                    if s == EMPTY:
                        continue
                    if labels[s] >= 0 and labels[s] != a:
                        n_seen = _remember(seen, n_seen, labels[s])
                    break
        for q in range(n_seen):
            if n == out.shape[0]:
                out = np.concatenate((out, np.empty_like(out)))
            out[n, 0] = a
            out[n, 1] = seen[q]
            n += 1
    return out[:n]


@dataclass(frozen=True)
class Learned:
    """A learned linkage for one frame: the model, how sure it must be, and each map slot's height above the road."""

    model: JoinModel
    min_probability: float  # linked parts it gives a higher chance of being one object are joined, rule or not
    height: npt.NDArray[np.float64]
    veto_below: float = 0.0  # ... and the rule's joins it is less sure of than this are not


def _root(parent: npt.NDArray[np.int64], x: int) -> int:
    while parent[x] != x:
        parent[x] = parent[parent[x]]
        x = int(parent[x])
    return x


def _pairs(links: npt.NDArray[np.int64], n_clusters: int) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """Distinct (a, b) pairs packed as a * n + b, and how many voxels of a link to b."""
    return np.unique(links[:, 0] * n_clusters + links[:, 1], return_counts=True)


def _judged(learned: Learned, vmap: VoxelMap, labels: I32, members: npt.NDArray[np.int64], n_clusters: int,
            position: npt.NDArray[np.float64], direct: LinkCounts, stepped: LinkCounts, big: npt.NDArray[np.bool_],
            xs: npt.NDArray[np.int64], ys: npt.NDArray[np.int64]) -> tuple[npt.NDArray[np.int64], ...]:
    """The rule's joins the model does not doubt, and the linked pairs it is sure of; its chance as their strength."""
    a, b, rows = pair_features(vmap, labels, members, n_clusters, position, learned.height, direct, stepped)
    judged = big[a] & big[b]  # only big parts are ever joined here: the rest is left to the aggregation
    a, b, rows = a[judged], b[judged], rows[judged]
    chance = learned.model.probability(rows)
    keys = a * n_clusters + b  # sorted: pair_features gives them in order
    ruled = np.minimum(xs, ys) * n_clusters + np.maximum(xs, ys)
    by_rule = np.zeros(len(keys), dtype=bool)
    if len(keys):
        by_rule[np.searchsorted(keys, ruled)] = True  # every pair the rule joins is a linked pair of big parts
    keep = (by_rule & (chance >= learned.veto_below)) | (chance > learned.min_probability)
    return a[keep], b[keep], chance[keep]


def part_links(vmap: VoxelMap, labels: I32, members: npt.NDArray[np.int64], n_clusters: int,
               position: npt.NDArray[np.float64], bridge_voxels: int,
               step_voxels: int) -> tuple[LinkCounts, LinkCounts]:
    """Voxel links between parts: through neighbours and bridges, and step links (none if ``step_voxels`` is 0)."""
    sight = vmap.centroids[members, :2] - position[:2]
    sight = np.ascontiguousarray(sight / np.maximum(np.hypot(sight[:, 0], sight[:, 1]), 1e-9)[:, None])
    table = (vmap.keys, vmap.table_keys, vmap.table_slots, vmap.shift)
    direct = _pairs(_links(members, labels, *table, DELTAS, sight, int(bridge_voxels), 0), n_clusters)
    if step_voxels <= 0:
        return direct, (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
    return direct, _pairs(_links(members, labels, *table, NO_DELTAS, sight, 0, int(step_voxels)), n_clusters)


def _join_unless_apart(parent: npt.NDArray[np.int64], xs: npt.NDArray[np.int64], ys: npt.NDArray[np.int64],
                       shares: npt.NDArray[np.float64], apart: Apart) -> None:
    """Joins (xs[i], ys[i]), the strongest links first, except where a part with an opinion on one side
    is kept apart from one on the other: a walker's coat, linked to his trousers (no corners of
    their own) and they to a wall, still stays off the wall."""
    opinions: dict[int, list[int]] = {int(i): [int(i)] for i in np.flatnonzero(apart.known)}
    for q in np.argsort(-shares, kind="stable"):
        rx, ry = _root(parent, int(xs[q])), _root(parent, int(ys[q]))
        if rx == ry:
            continue
        ox, oy = opinions.get(rx, []), opinions.get(ry, [])
        if ox and oy and apart(np.repeat(ox, len(oy)), np.tile(oy, len(ox))).any():
            continue
        low, high = min(rx, ry), max(rx, ry)
        parent[high] = low
        if ox or oy:
            opinions[low] = ox + oy


def join_parts(vmap: VoxelMap, labels: I32, n_clusters: int, position: npt.NDArray[np.float64], min_voxels: int,
               min_share: float, bridge_voxels: int, step_voxels: int = 0, apart: Apart | None = None,
               learned: Learned | None = None) -> I32:
    """Labels with strongly linked big clusters given one label (see the module text); no two parts
    that ``apart`` keeps apart end in one, nor do the objects they were joined into first. With
    ``learned``, its model may join linked big parts the rule leaves apart, and part those it joins."""
    members = np.flatnonzero(labels >= 0)
    if members.size == 0 or (min_share > 1.0 and learned is None):
        return labels
    sizes = np.bincount(labels[members], minlength=n_clusters)
    big = sizes >= min_voxels
    direct, stepped = part_links(vmap, labels, members, n_clusters, position, bridge_voxels, step_voxels)
    packed, counts = direct
    a, b = packed // n_clusters, packed % n_clusters
    strong = big[a] & big[b] & (counts >= min_share * sizes[a])
    joins = [(a[strong], b[strong], counts[strong] / sizes[a[strong]])]
    if step_voxels > 0:
        # a step link must be seen from both parts: a car's roof links up to a hedge behind it too,
        # but the hedge stands on the road and has no bottom in the air to look back down from
        packed, counts = stepped
        a, b = packed // n_clusters, packed % n_clusters
        strong = big[a] & big[b] & (counts >= min_share * sizes[a]) & np.isin(b * n_clusters + a, packed)
        joins.append((a[strong], b[strong], counts[strong] / sizes[a[strong]]))
    xs, ys, shares = (np.concatenate(j) for j in zip(*joins, strict=True))
    if learned is not None:
        xs, ys, shares = _judged(learned, vmap, labels, members, n_clusters, position, direct, stepped, big, xs, ys)
    parent = np.arange(n_clusters)
    if apart is None:
        for x, y in zip(xs, ys, strict=True):
            rx, ry = _root(parent, int(x)), _root(parent, int(y))
            if rx != ry:
                parent[max(rx, ry)] = min(rx, ry)
    else:
        _join_unless_apart(parent, xs, ys, shares, apart)
    roots = np.array([_root(parent, i) for i in range(n_clusters)], dtype=np.int32)
    out = labels.copy()
    out[members] = roots[labels[members]]
    return out
