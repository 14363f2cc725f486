"""Cluster refinement: aggregation of small clusters (Alg. IV-B.2) and noise removal (Alg. IV-B.3).

Disparity noise leaves small clusters on objects (a speck of another colour, a voxel seen in
shadow). Each small cluster that touches a big one (26-neighbourhood) is aggregated into the
biggest it touches; what is still small, or sparse (voxels / bounding-box volume in voxels
below ``min_density``), is noise and dropped.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

I32 = npt.NDArray[np.int32]


def aggregate(labels: I32, n_clusters: int, pairs: npt.NDArray[np.int64], min_voxels: int) -> I32:
    """Relabel every small cluster touching a big one with the biggest such neighbour's label."""
    sizes = np.bincount(labels[labels >= 0], minlength=n_clusters)
    if pairs.shape[0] == 0:
        return labels
    a, b = pairs[:, 0], pairs[:, 1]
    # Each contact seen from the small side: (small, neighbour) where the neighbour is big.
    small_a = (sizes[a] < min_voxels) & (sizes[b] >= min_voxels)
    small_b = (sizes[b] < min_voxels) & (sizes[a] >= min_voxels)
    small = np.concatenate((a[small_a], b[small_b]))
    big = np.concatenate((b[small_a], a[small_b]))
    if small.size == 0:
        return labels
    # For each small cluster keep the neighbour of largest size (ties: the lower label).
    order = np.lexsort((big, -sizes[big], small))
    small, big = small[order], big[order]
    first = np.concatenate(([True], small[1:] != small[:-1]))
    target = np.arange(n_clusters)
    target[small[first]] = big[first]
    out = labels.copy()
    assigned = out >= 0
    out[assigned] = target[out[assigned]]
    return out


def density(coords: npt.NDArray[np.int32], labels: I32, n_clusters: int) -> tuple[npt.NDArray[np.int64], np.ndarray]:
    """Voxel count and density (count / bounding-box volume in voxels) of every label."""
    inside = labels >= 0
    lab, xyz = labels[inside], coords[inside].astype(np.int64)
    sizes = np.bincount(lab, minlength=n_clusters)
    lo = np.full((n_clusters, 3), np.iinfo(np.int64).max)
    hi = np.full((n_clusters, 3), np.iinfo(np.int64).min)
    np.minimum.at(lo, lab, xyz)
    np.maximum.at(hi, lab, xyz)
    box = np.prod(np.maximum(hi - lo + 1, 1), axis=1)
    return sizes, np.where(sizes > 0, sizes / box, 0.0)


def remove_noise(labels: I32, coords: npt.NDArray[np.int32], n_clusters: int, min_voxels: int,
                 min_density: float) -> I32:
    """Labels with small or sparse clusters set to -1."""
    sizes, dens = density(coords, labels, n_clusters)
    noise = (sizes < min_voxels) | (dens < min_density)
    out = labels.copy()
    assigned = np.flatnonzero(out >= 0)
    out[assigned[noise[out[assigned]]]] = -1
    return out
