"""Two linked parts as a learned linkage sees them: one row of numbers per pair (join_model.py).

The flood fill's parts are nearly pure: on synthetic held-out urban, 95 % of them have nine in
ten of their voxels nearest one object, and 96 % of all their voxels lie nearest their part's.
What goes wrong is which parts are joined. Joined by the ground truth instead of by
``voxel.join_share``, the same parts give held-out urban 90 % of its objects in one cluster,
against 80 % (docs/results/voxel.md, "Session 53"). The hand-made rule looks at one number, the
share of a part's voxels linked to the other; these rows give a model that share both ways, the
step links, colour, size, height, shape along and across the line of sight, and how far apart the
parts lie, so that a walker's coat and trousers join while the walker and the bin he passes do
not.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from services.voxel_mapper.voxel_map import VoxelMap, colour_stats

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

#: the columns of :func:`pair_features`; "small" is the pair's part with fewer voxels, "big" the other.
FEATURES: tuple[str, ...] = (
    "log_voxels_small", "log_voxels_big",  # part sizes
    "link_share_small", "link_share_big",  # share of each part's voxels linked to the other (26 + bridge)
    "step_share_small", "step_share_big",  # ... by a step link (one layer up and away, or down and nearer)
    "rgb_distance", "hsl_distance",  # the parts' mean colours: L2 in RGB, L1 in HSL (Eq. 1's two terms)
    "floor_small", "floor_big", "top_small", "top_big",  # lowest and highest voxel above the road (m)
    "across_small", "across_big", "along_small", "along_big",  # extent across / along the line of sight (m)
    "centre_gap", "height_overlap",  # distance between the parts' centres seen from above (m); shared height
    "across_both", "along_both",  # the extent of both together across / along the line of sight (m)
    "range", "tall_small", "tall_big",  # mean range from the camera (m); each part's height (m)
)  # fmt: skip

LinkCounts = tuple[I64, I64]  # packed a * n + b, and how many voxels of a link to b (linkage._pairs)


def _count(links: LinkCounts, keys: I64) -> F64:
    """Link counts for packed keys (0 where there is none)."""
    packed, counts = links
    if packed.size == 0 or keys.size == 0:
        return np.zeros(keys.size)
    at = np.minimum(np.searchsorted(packed, keys), packed.size - 1)
    return np.where(packed[at] == keys, counts[at], 0).astype(np.float64)


def _span(lo: F64, hi: F64, along: F64, edge: float) -> tuple[F64, F64]:
    """Extents (m) of axis-aligned boxes across and along unit directions ``along`` (x, y)."""
    ext = hi[:, :2] - lo[:, :2]
    deep = np.abs(ext[:, 0] * along[:, 0] + ext[:, 1] * along[:, 1]) + edge
    wide = np.abs(-ext[:, 0] * along[:, 1] + ext[:, 1] * along[:, 0]) + edge
    return wide, deep


def pair_features(vmap: VoxelMap, labels: npt.NDArray[np.int32], members: I64, n_parts: int, position: F64,
                  height: F64, direct: LinkCounts, stepped: LinkCounts) -> tuple[I64, I64, F64]:
    """Every pair of parts linked either way (a < b) and its row of :data:`FEATURES`.

    ``members`` are the map slots with a part, ``height`` every slot's height above the road.
    """
    keys = np.concatenate([direct[0], stepped[0]])
    a, b = keys // n_parts, keys % n_parts
    pair = np.unique(np.minimum(a, b) * n_parts + np.maximum(a, b))
    a, b = pair // n_parts, pair % n_parts
    if pair.size == 0:
        return a, b, np.zeros((0, len(FEATURES)))

    lab = labels[members]
    order = np.argsort(lab, kind="stable")  # each part's voxels together, for reduceat
    slots, lab = members[order], lab[order]
    present, starts = np.unique(lab, return_index=True)
    centres = vmap.centroids[slots]
    up = height[slots]
    ranges = np.hypot(centres[:, 0] - position[0], centres[:, 1] - position[1])

    def per_part(values: F64, reduce: np.ufunc, fill: float) -> F64:
        out = np.full((n_parts, *values.shape[1:]), fill)
        out[present] = reduce.reduceat(values, starts, axis=0)
        return out

    sizes = np.bincount(lab, minlength=n_parts).astype(np.float64)
    sums = per_part(vmap.stats[slots], np.add, 0.0)
    sums[sizes == 0, 0] = 1.0  # parts with no voxel left (never in a pair) must not divide by zero
    rgb = colour_stats(sums, "rgb")[0]
    hsl = colour_stats(sums, "hsl", vmap.circular_hue)[0]
    middle = per_part(centres[:, :2], np.add, 0.0) / np.maximum(sizes, 1.0)[:, None]
    lo, hi = per_part(centres, np.minimum, np.inf), per_part(centres, np.maximum, -np.inf)
    floor, top = per_part(up, np.minimum, np.inf), per_part(up, np.maximum, -np.inf)
    dist = per_part(ranges, np.add, 0.0) / np.maximum(sizes, 1.0)

    small = np.where(sizes[a] <= sizes[b], a, b)
    big = np.where(sizes[a] <= sizes[b], b, a)
    sight = 0.5 * (middle[a] + middle[b]) - position[:2]
    sight /= np.maximum(np.hypot(sight[:, 0], sight[:, 1]), 1e-9)[:, None]
    edge = vmap.edge
    across_s, along_s = _span(lo[small], hi[small], sight, edge)
    across_b, along_b = _span(lo[big], hi[big], sight, edge)
    across_u, along_u = _span(np.minimum(lo[a], lo[b]), np.maximum(hi[a], hi[b]), sight, edge)
    shared = np.maximum(0.0, np.minimum(hi[a, 2], hi[b, 2]) - np.maximum(lo[a, 2], lo[b, 2]) + edge)
    overlap = shared / (np.minimum(hi[a, 2] - lo[a, 2], hi[b, 2] - lo[b, 2]) + edge)
    n = n_parts
    rows = np.column_stack([
        np.log(sizes[small]), np.log(sizes[big]),
        _count(direct, small * n + big) / sizes[small], _count(direct, big * n + small) / sizes[big],
        _count(stepped, small * n + big) / sizes[small], _count(stepped, big * n + small) / sizes[big],
        np.linalg.norm(rgb[a] - rgb[b], axis=1), np.abs(hsl[a] - hsl[b]).sum(axis=1),
        floor[small], floor[big], top[small], top[big],
        across_s, across_b, along_s, along_b,
        np.hypot(*(middle[a] - middle[b]).T), overlap, across_u, along_u,
        0.5 * (dist[a] + dist[b]), top[small] - floor[small], top[big] - floor[big],
    ])  # fmt: skip
    return a, b, rows
