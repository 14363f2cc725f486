"""Cluster refinement: aggregation of small clusters (Alg. IV-B.2) and noise removal (Alg. IV-B.3).

Disparity noise leaves small clusters on objects (a speck of another colour, a voxel seen in
shadow), and colour splits a small object into pieces (a walker's coat, trousers and head).
Each small cluster that touches a big one (26-neighbourhood) is aggregated into the biggest it
touches; what is still small, or sparse (voxels / bounding-box volume in voxels below
``min_density``), is noise and dropped (Alg. IV-B.3).

The paper's pseudo-code takes the clusters in turn and aggregates a small one into its biggest
neighbour whatever that one's size, so pieces that are each small add up. ``aggregate`` does
that for the clusters marked ``in_turn`` (``voxel.aggregate_in_turn_m``: those nearer than that).
Measured in session 33 (docs/results/voxel.md): a walker at 17 m seen as pieces of 12, 13, 4, 3
and 1 voxels (the noise limit is 20) touches no big cluster and is dropped whole (synthetic
crossing-s7, frames 34-37); taken in turn his pieces are one cluster. Everywhere, it gave
held-out crossing 71.8 -> 80.8 % moving TP but KITTI tracking 0001 41 false moving frames
against 3: far vegetation's pieces added up and the tracker slid along them. It is off.
"""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

I32 = npt.NDArray[np.int32]


@numba.njit(cache=True)
def _root(parent: npt.NDArray[np.int64], x: int) -> int:
    while parent[x] != x:
        parent[x] = parent[parent[x]]
        x = parent[x]
    return x


@numba.njit(cache=True)
def _in_turn(sizes: npt.NDArray[np.int64], starts: npt.NDArray[np.int64], neighbours: npt.NDArray[np.int64],
             min_voxels: int, any_size: npt.NDArray[np.bool_]) -> npt.NDArray[np.int64]:
    """Alg. IV-B.2 in label order over the contact graph (CSR): each cluster's final label.

    A small cluster joins its biggest neighbour; where ``any_size`` is False only if that one
    already has ``min_voxels``.
    """
    n = sizes.shape[0]
    size = sizes.copy()
    parent = np.arange(n)
    for c in range(n):
        r = _root(parent, c)
        if size[r] >= min_voxels:
            continue
        best, best_size = -1, -1
        for k in range(starts[c], starts[c + 1]):
            q = _root(parent, neighbours[k])
            if q != r and (size[q] > best_size or (size[q] == best_size and q < best)):
                best, best_size = q, size[q]
        if best >= 0 and (any_size[c] or best_size >= min_voxels):
            parent[r] = best
            size[best] += size[r]
    for c in range(n):
        parent[c] = _root(parent, c)
    return parent


def aggregate(labels: I32, n_clusters: int, pairs: npt.NDArray[np.int64], min_voxels: int,
              in_turn: npt.NDArray[np.bool_] | None = None) -> I32:
    """Relabel small clusters with their biggest touching neighbour's label (Alg. IV-B.2).

    Without ``in_turn`` (n_clusters,) only a neighbour already big is joined, all at once. With
    it the clusters are taken one after the other, and those it marks join their biggest
    neighbour of any size.
    """
    if pairs.shape[0] == 0:
        return labels
    sizes = np.bincount(labels[labels >= 0], minlength=n_clusters)
    if in_turn is not None:
        both = np.concatenate((pairs, pairs[:, ::-1])).astype(np.int64)
        both = both[np.lexsort((both[:, 1], both[:, 0]))]
        starts = np.searchsorted(both[:, 0], np.arange(n_clusters + 1))
        target = _in_turn(sizes.astype(np.int64), starts, both[:, 1].copy(), min_voxels, in_turn)
    else:
        target = _into_big(sizes, pairs, min_voxels)
    out = labels.copy()
    assigned = out >= 0
    out[assigned] = target[out[assigned]]
    return out


def _into_big(sizes: npt.NDArray[np.int64], pairs: npt.NDArray[np.int64], min_voxels: int) -> npt.NDArray[np.int64]:
    """Each cluster's label after joining small ones to their biggest neighbour already big, all at once."""
    a, b = pairs[:, 0], pairs[:, 1]
    # Each contact seen from the small side: (small, neighbour) where the neighbour is big.
    small_a = (sizes[a] < min_voxels) & (sizes[b] >= min_voxels)
    small_b = (sizes[b] < min_voxels) & (sizes[a] >= min_voxels)
    small = np.concatenate((a[small_a], b[small_b]))
    big = np.concatenate((b[small_a], a[small_b]))
    target = np.arange(len(sizes))
    if small.size == 0:
        return target
    # For each small cluster keep the neighbour of largest size (ties: the lower label).
    order = np.lexsort((big, -sizes[big], small))
    small, big = small[order], big[order]
    first = np.concatenate(([True], small[1:] != small[:-1]))
    target[small[first]] = big[first]
    return target


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
