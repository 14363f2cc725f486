"""What each cluster carries out of step 4: voxels, count, colour, box, centroid, density, volume.

Each voxel also carries the points this frame put in it, so that the tracker can place a
cluster where its points are rather than where its voxels are (services/tracker/anchor.py).

Colour mean and variance pool every point of the cluster's voxels (from the per-voxel sums), so a
voxel seen by many points weighs more than one seen once. The centroid is the median, axis by
axis, of the voxels' point centroids (each voxel once, so near surfaces, which collect many more
points, do not pull it, and a few stray voxels of smear do not either). The box spans the voxel
centroids grown by half an edge, which follows the surface to within a few centimetres where
whole voxel cells would add up to an edge on each side.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from common.messages import Cluster
from services.voxel_mapper.voxel_map import XYZ, VoxelMap, colour_stats


def describe(vmap: VoxelMap, labels: npt.NDArray[np.int32], height: npt.NDArray[np.float64]) -> list[Cluster]:
    """One Cluster per distinct label >= 0, ids numbered 0.. in order of decreasing size; ``height``
    is each voxel's above the road, whose least over a cluster is its floor."""
    slots = np.flatnonzero(labels >= 0)
    if slots.size == 0:
        return []
    lab = labels[slots]
    order = np.argsort(lab, kind="stable")
    slots, lab = slots[order], lab[order]
    starts = np.flatnonzero(np.concatenate(([True], lab[1:] != lab[:-1])))
    counts = np.diff(np.append(starts, slots.size))

    stats = vmap.stats[slots]
    coords = vmap.coords[slots]
    hits = np.rint(vmap.hits[slots]).astype(np.int32)
    centroids = stats[:, XYZ] / stats[:, 0:1]
    sums = np.add.reduceat(stats, starts, axis=0)
    rgb_mean, rgb_var = (a.astype(np.float32) for a in colour_stats(sums, "rgb"))
    hsl_mean, hsl_var = (a.astype(np.float32) for a in colour_stats(sums, "hsl", vmap.circular_hue))
    centre = np.array([np.median(centroids[s:s + n], axis=0) for s, n in zip(starts, counts, strict=True)])
    half = 0.5 * vmap.edge
    box_lo = np.minimum.reduceat(centroids, starts, axis=0) - half
    box_hi = np.maximum.reduceat(centroids, starts, axis=0) + half
    cells = np.maximum.reduceat(coords, starts, axis=0) - np.minimum.reduceat(coords, starts, axis=0) + 1
    dens = counts / np.prod(cells.astype(np.float64), axis=1)
    volume = counts * vmap.edge**3
    floor = np.minimum.reduceat(height[slots], starts)

    out = []
    for rank, c in enumerate(np.argsort(-counts, kind="stable")):
        s = starts[c]
        out.append(Cluster(
            id=rank,
            voxels=np.ascontiguousarray(coords[s:s + counts[c]], dtype=np.int32),
            voxel_count=int(counts[c]),
            voxel_points=hits[s:s + counts[c]].copy(),
            color_mean_rgb=rgb_mean[c], color_var_rgb=rgb_var[c],
            color_mean_hsl=hsl_mean[c], color_var_hsl=hsl_var[c],
            bbox_min=box_lo[c], bbox_max=box_hi[c], centroid=centre[c],
            density=float(dens[c]), volume=float(volume[c]), floor_m=float(floor[c]),
        ))
    return out
