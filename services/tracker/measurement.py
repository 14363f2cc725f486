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

import numba
import numpy as np
import numpy.typing as npt

from common.config import VolumeConfig

NDArray = npt.NDArray[Any]


def stereo_covariance(points: NDArray, eye: NDArray, base_std: float, per_m2: float) -> NDArray:
    """(n, 3, 3): ``base_std`` across the ray from ``eye``, plus ``per_m2 * range^2`` along it.

    Compiled, cluster by cluster, as ``cut_covariance``: over numpy's arrays the two took 60 µs a
    frame with 50 clusters, a twentieth of the tracker's time.
    """
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    return _stereo_covariance(points, np.asarray(eye, dtype=np.float64), float(base_std), float(per_m2))


@numba.njit(cache=True)
def _stereo_covariance(points: NDArray, eye: NDArray, base_std: float, per_m2: float) -> NDArray:
    out = np.zeros((points.shape[0], 3, 3))
    unit = np.empty(3)
    for c in range(points.shape[0]):
        r0, r1, r2 = points[c, 0] - eye[0], points[c, 1] - eye[1], points[c, 2] - eye[2]
        distance = np.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
        scale = max(distance, 1e-9)
        unit[0], unit[1], unit[2] = r0 / scale, r1 / scale, r2 / scale
        along = (base_std + per_m2 * distance**2) ** 2 - base_std**2
        for i in range(3):
            for j in range(3):
                out[c, i, j] = along * unit[i] * unit[j]
            out[c, i, i] += base_std**2
    return out


def cut_covariance(
    bbox_min: NDArray, bbox_max: NDArray, pose: NDArray, volume: VolumeConfig, margin: float, slice_m: float = 0.0
) -> NDArray:
    """(n, 3, 3): along each vehicle axis where a box reaches the volume's limits, its own extent squared.

    A box reaching within ``margin`` of the near or far end is cut along the vehicle's x, one
    reaching a side along its y, and along x as well if it reaches in from that side by less than
    ``slice_m``; across the cut the centroid is as good as ever. The road below and the sky above
    do not cut obstacles sideways, so z limits do not count.
    """
    n = len(bbox_min)
    lo_box = np.ascontiguousarray(bbox_min, dtype=np.float64).reshape(n, 3)
    hi_box = np.ascontiguousarray(bbox_max, dtype=np.float64).reshape(n, 3)
    limits = np.array([volume.x_min + margin, volume.x_max - margin, volume.y_half - margin, volume.y_half, slice_m])
    return _cut_covariance(lo_box, hi_box, np.ascontiguousarray(pose, dtype=np.float64), limits)


@numba.njit(cache=True)
def _cut_covariance(bbox_min: NDArray, bbox_max: NDArray, pose: NDArray, limits: NDArray) -> NDArray:
    """``cut_covariance`` box by box; ``limits`` the volume's near and far x and side y less the
    margin, its side y, and ``slice_m``."""
    near, far, side, y_half, slice_m = limits[0], limits[1], limits[2], limits[3], limits[4]
    out = np.zeros((bbox_min.shape[0], 3, 3))
    lo, hi = np.empty(2), np.empty(2)
    for c in range(bbox_min.shape[0]):
        # the box in the vehicle's axes: its centre turned, its half extents through |R^T| (the corners' hull)
        for a in range(2):
            centre = half = 0.0
            for k in range(3):
                centre += (0.5 * (bbox_min[c, k] + bbox_max[c, k]) - pose[k, 3]) * pose[k, a]
                half += (0.5 * (bbox_max[c, k] - bbox_min[c, k])) * abs(pose[k, a])
            lo[a], hi[a] = centre - half, centre + half
        cut_x = lo[0] <= near or hi[0] >= far
        cut_y = max(-lo[1], hi[1]) >= side
        inner = lo[1] if hi[1] >= side else -hi[1]  # |y| of its edge inside
        cut_x = cut_x or (cut_y and y_half - inner < slice_m)
        var_x = (hi[0] - lo[0]) ** 2 if cut_x else 0.0
        var_y = (hi[1] - lo[1]) ** 2 if cut_y else 0.0
        for i in range(3):
            for j in range(3):
                out[c, i, j] = var_x * (pose[i, 0] * pose[j, 0]) + var_y * (pose[i, 1] * pose[j, 1])
    return out


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
