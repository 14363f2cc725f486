"""How far a cluster's centroid can be trusted as the position of its object.

Four things move a centroid while the object stands still, and each gets its own variance:

- stereo: depth error grows with the square of the range and lies along the viewing ray
  (``sigma_z = z^2 sigma_d / (f b)``), so a cluster 25 m ahead jitters by tenths of a metre
  along the ray and by little across it;
- visibility: driving past a parked car its side comes into view, or an occluder uncovers it,
  and the centroid slides by up to half the change of the box's extent; along an axis whose
  extent changed by ``de`` the centroid is given a further standard deviation of ``de``;
- the volume of interest: a cluster touching its boundary is cut by it, and the cut slides with
  the vehicle (a parked car entering at the far end grows at the vehicle's speed); its centroid
  only says where the object is to within its own extent, along the axis the cut crosses. A
  cluster reaching in from a side by less than a car's width is a slice of something standing
  outside (a hedge, a facade, a parked car beyond the side), and where its slice begins and ends
  along the road changes as the vehicle moves: it is unreliable along x too. On KITTI 0001 the
  false moving frames went 16 -> 5 with this (docs/results/tracking.md, "Session 22").
- the image's side edges: a box straddling the line of sight that reaches them (an overhead sign
  or a gantry a few metres ahead, a wall across the road) is followed at the middle of what is in
  view, which slides sideways as the edges close in; across the road it says where the object is
  only to within its own width. On synthetic hanging this took the false moving share back from
  8.0 to 5.9 % once cut clusters were followed at their far end (docs/results/tracking.md,
  "Session 24").
The filter then reads a velocity only out of what a rigid object's centroid does, and the speed's
standard deviation it reports stays honest, which the moving label relies on.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from common.config import VolumeConfig

NDArray = npt.NDArray[Any]


def stereo_covariance(points: NDArray, eye: NDArray, base_std: float, per_m2: float) -> NDArray:
    """(n, 3, 3): ``base_std`` across the ray from ``eye``, plus ``per_m2 * range^2`` along it."""
    ray = points - eye
    distance = np.linalg.norm(ray, axis=1)
    unit = ray / np.maximum(distance, 1e-9)[:, None]
    along = (base_std + per_m2 * distance**2) ** 2 - base_std**2
    return base_std**2 * np.eye(3) + along[:, None, None] * unit[:, :, None] * unit[:, None, :]


def cut_covariance(
    bbox_min: NDArray, bbox_max: NDArray, pose: NDArray, volume: VolumeConfig, margin: float, slice_m: float = 0.0
) -> NDArray:
    """(n, 3, 3): along each vehicle axis where a box reaches the volume's limits, its own extent squared.

    A box reaching within ``margin`` of the near or far end is cut along the vehicle's x, one
    reaching a side along its y, and along x as well if it reaches in from that side by less than
    ``slice_m``; across the cut the centroid is as good as ever. The road below and the sky above
    do not cut obstacles sideways, so z limits do not count.
    """
    # the box in the vehicle's axes: its centre turned, its half extents through |R^T| (the corners' hull)
    rotation = pose[0:3, 0:3]
    centre = (0.5 * (bbox_min + bbox_max) - pose[0:3, 3]) @ rotation
    half = (0.5 * (bbox_max - bbox_min)) @ np.abs(rotation)
    lo, hi = centre - half, centre + half
    cut_x = (lo[:, 0] <= volume.x_min + margin) | (hi[:, 0] >= volume.x_max - margin)
    cut_y = np.maximum(-lo[:, 1], hi[:, 1]) >= volume.y_half - margin
    inner = np.where(hi[:, 1] >= volume.y_half - margin, lo[:, 1], -hi[:, 1])  # |y| of its edge inside
    cut_x |= cut_y & (volume.y_half - inner < slice_m)
    var_x = np.where(cut_x, (hi[:, 0] - lo[:, 0]) ** 2, 0.0)
    var_y = np.where(cut_y, (hi[:, 1] - lo[:, 1]) ** 2, 0.0)
    ax, ay = pose[0:3, 0], pose[0:3, 1]
    return var_x[:, None, None] * np.outer(ax, ax) + var_y[:, None, None] * np.outer(ay, ay)


def view_cut_covariance(extent: NDArray, pose: NDArray) -> NDArray:
    """(n, 3, 3): along the vehicle's y, the squared width of boxes the image's side edges cut sideways."""
    ay = pose[0:3, 1]
    return extent[:, 1, None, None] ** 2 * np.outer(ay, ay)


def visibility_covariance(extent: NDArray, prev_extent: NDArray) -> NDArray:
    """(n, 3, 3) diagonal: the change of the box's extent along each axis, squared."""
    out = np.zeros((len(extent), 3, 3))
    idx = np.arange(3)
    out[:, idx, idx] = (extent - prev_extent) ** 2
    return out
