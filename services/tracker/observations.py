"""One frame's clusters as arrays, with the unusable ones (non-finite geometry) left out."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
import numpy.typing as npt

from common.messages import Cluster
from services.tracker.anchor import Footprint, anchors, footprint

NDArray = npt.NDArray[Any]


@dataclass(frozen=True)
class Observations:
    """Features of ``m`` clusters, row ``i`` from cluster ``index[i]`` of the message."""

    index: NDArray  # (m,) position in the message's cluster list
    centroid: NDArray  # (m, 3)
    anchors: NDArray  # (m, 3, 3) the points the filter may follow, one per side (anchor.py)
    side: NDArray  # (m,) the side in view
    far: NDArray  # (m, 3) from the near end to the far end of the cluster along the vehicle's x
    narrow: NDArray  # (m,) followed at the middle range of its points, not its near face (anchor.py)
    cut: NDArray  # (m,) its near end is where the image's side edge cuts it: followed at its far end
    across: NDArray  # (m,) how wide its points are across the line of sight (m, 5-95 %; NaN: unknown)
    depth: NDArray  # (m,) how deep their middle half lies along it (m, 25-75 %; NaN: unknown or not narrow)
    bbox_min: NDArray
    bbox_max: NDArray
    rgb: NDArray
    hsl: NDArray
    density: NDArray  # (m,)
    volume: NDArray
    floor: NDArray  # (m,) height of its lowest voxel above the road (m)

    @cached_property
    def extent(self) -> NDArray:
        return self.bbox_max - self.bbox_min

    @cached_property
    def anchor(self) -> NDArray:
        """(m, 3) the point on the side in view."""
        return self.anchors[np.arange(len(self)), self.side]

    @cached_property
    def followed(self) -> NDArray:
        """(m, 3) the point the filter measures: the anchor, or its far end where the near one is cut."""
        return self.anchor + self.far * self.cut[:, None]

    def __len__(self) -> int:
        return int(self.index.shape[0])

    def take(self, rows: NDArray) -> Observations:
        """The subset of rows ``rows``."""
        return Observations(*(getattr(self, name)[rows] for name in self.__dataclass_fields__))


def observe(
    clusters: list[Cluster], pose: NDArray, edge: float, view: NDArray | None = None, view_margin: float = 0.0
) -> tuple[Observations, Footprint, int]:
    """Stack the clusters' features; return them, the kept clusters' voxels, and how many were dropped
    as non-finite.

    A cluster with a NaN or infinite centroid, box, colour or density cannot be predicted, compared
    or filtered, and one bad row would poison the whole batched filter, so it is dropped here.
    """
    n = len(clusters)
    # one concatenation a kind: a stack per field cost twice as much
    geometry = np.concatenate([a for c in clusters for a in (c.centroid, c.bbox_min, c.bbox_max)] or [np.zeros(0)])
    colour = np.concatenate([a for c in clusters for a in (c.color_mean_rgb, c.color_mean_hsl)] or [np.zeros(0)])
    geometry = geometry.astype(np.float64).reshape(n, 9)
    colour = colour.astype(np.float64).reshape(n, 6)
    scalars = np.array([(c.density, c.volume, c.floor_m) for c in clusters], dtype=np.float64).reshape(n, 3)
    finite = np.isfinite(geometry).all(axis=1) & np.isfinite(colour).all(axis=1) & np.isfinite(scalars).all(axis=1)
    keep = np.flatnonzero(finite)
    kept = [clusters[i] for i in keep.tolist()]
    stacked = footprint(kept)
    points, side, far, narrow, cut, spread = anchors(kept, geometry[keep, 0:3], pose, edge, view, view_margin, stacked)
    obs = Observations(
        index=keep,
        centroid=geometry[keep, 0:3],
        anchors=points,
        side=side,
        far=far,
        narrow=narrow,
        cut=cut,
        across=spread[:, 0],
        depth=spread[:, 1],
        bbox_min=geometry[keep, 3:6],
        bbox_max=geometry[keep, 6:9],
        rgb=colour[keep, 0:3],
        hsl=colour[keep, 3:6],
        density=scalars[keep, 0],
        volume=scalars[keep, 1],
        floor=scalars[keep, 2],
    )
    return obs, stacked, n - int(keep.shape[0])
