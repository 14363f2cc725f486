"""Walkers in a group told apart by where this frame's points stand densest, seen from above.

Two or three people crossing together, a metre apart, are one cluster: stereo smear at 15-35 m
fills the gap between them with voxels, and their coats need not differ by more than the flood
fill's epsilon. Seen from above they still stand apart. A person is a vertical surface about
0.5 m across, so every column of voxels (sharing x and y) through his body holds many of this
frame's points, while the smear between two people is a sparse fringe of a few points per column.
On synthetic crossing seed 8, frames 26-32, the columns holding at least a fifth of the cluster's
densest column's points formed three 8-connected patches, each within 0.2 m of one of the three
walkers merged there.

So in a cluster standing at least ``TALL_M`` high, the columns holding ``dense_share`` of its
densest column's points are grouped into 8-connected patches. The cluster is cut, each voxel going
to the nearest patch, when every patch is a core and there are two or more, and at most
``MAX_CORES``. A core is no wider than ``CORE_M`` either way (a person, a pole; a car's rear or a
facade is wider), reaches no higher than ``PERSON_M`` (a gantry's posts, poles and trees do) and
holds at least ``CORE_SHARE`` of the cluster's points. Each piece must keep
``min_voxels``: below that the pieces were the two halves of a car or a pole and its own smear,
and became phantom obstacles. Measured on tracker-and-mapper replays (docs/results/voxel.md,
"Session 22"); the constants were set once, not swept.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from services.voxel_mapper.skyline import EIGHT

I32 = npt.NDArray[np.int32]
F64 = npt.NDArray[np.float64]

#: widest core, either way (m)
CORE_M: float = 1.0
#: least share of the cluster's points a core holds
CORE_SHARE: float = 0.15
#: lowest cluster cut (m, its voxels' span in height)
TALL_M: float = 1.2
#: most cores a cut cluster has
MAX_CORES: int = 3
#: highest core above the cluster's lowest voxel (m): a person, not a gantry's post or a pole
PERSON_M: float = 2.5


def split_groups(
    labels: I32, n_clusters: int, coords: I32, hits: F64, dense_share: float, min_voxels: int, edge: float
) -> tuple[I32, int]:
    """Labels with each group of compact cores cut into one cluster per core, and the new label count.

    ``hits``: this frame's points per voxel slot; ``dense_share`` 0 turns the cut off.
    """
    members = np.flatnonzero(labels >= 0)
    if members.size == 0 or dense_share <= 0.0:
        return labels, n_clusters
    lab = labels[members]
    order = np.argsort(lab, kind="stable")
    members, lab = members[order], lab[order]
    starts = np.flatnonzero(np.concatenate(([True], lab[1:] != lab[:-1])))
    ends = np.append(starts[1:], members.size)
    core_cols = max(round(CORE_M / edge), 1)
    tall_layers = TALL_M / edge
    out = labels
    for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
        if e - s < 2 * min_voxels:  # no two pieces could keep min_voxels each
            continue
        slots = members[s:e]
        height = coords[slots, 2]
        if height.max() - height.min() + 1 < tall_layers - 1e-9:
            continue
        ij = coords[slots, :2].astype(np.int64)
        ij -= ij.min(axis=0)
        shape = tuple(ij.max(axis=0) + 1)
        if max(shape) <= core_cols:  # one person's width: nothing to cut
            continue
        columns = np.zeros(shape)
        np.add.at(columns, (ij[:, 0], ij[:, 1]), hits[slots])
        patches, n_patches = ndimage.label(columns >= dense_share * columns.max(), structure=EIGHT)
        if not 2 <= n_patches <= MAX_CORES:
            continue
        spans = ndimage.find_objects(patches)
        if any(a.stop - a.start > core_cols or b.stop - b.start > core_cols for a, b in spans):
            continue
        index = range(1, n_patches + 1)
        if np.min(ndimage.sum(columns, patches, index)) < CORE_SHARE * columns.sum():
            continue
        core_of = patches[ij[:, 0], ij[:, 1]]
        top = np.zeros(n_patches + 1, dtype=np.int64)
        np.maximum.at(top, core_of, height - height.min() + 1)
        if top[1:].max() > PERSON_M / edge + 1e-9:
            continue
        centres = np.array(ndimage.center_of_mass(columns, patches, index))
        nearest = np.argmin(((ij[:, None, :] - centres[None, :, :]) ** 2).sum(axis=2), axis=1)
        if np.bincount(nearest, minlength=n_patches).min() < min_voxels:
            continue
        if out is labels:
            out = labels.copy()
        new = np.concatenate(([lab[s]], np.arange(n_clusters, n_clusters + n_patches - 1)))
        out[slots] = new[nearest]
        n_clusters += n_patches - 1
    return out, n_clusters
