"""How far a cluster's centroid can be trusted as the position of its object.

Three things move a centroid while the object stands still, and each gets its own variance:

- stereo: depth error grows with the square of the range and lies along the viewing ray
  (``sigma_z = z^2 sigma_d / (f b)``), so a cluster 25 m ahead jitters by tenths of a metre
  along the ray and by little across it;
- visibility: driving past a parked car its side comes into view, or an occluder uncovers it,
  and the centroid slides by up to half the change of the box's extent; along an axis whose
  extent changed by ``de`` the centroid is given a further standard deviation of ``de``;
- the volume of interest: a cluster touching its boundary is cut by it, and the cut slides with
  the vehicle (a parked car entering at the far end grows at the vehicle's speed); its centroid
  only says where the object is to within its own extent.
The filter then reads a velocity only out of what a rigid object's centroid does, and the speed's
standard deviation it reports stays honest, which the moving label relies on.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from common.config import VolumeConfig
from common.geometry import invert

NDArray = npt.NDArray[Any]

#: the 8 corners of a unit box, as weights of (min, max).
_CORNERS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=np.float64)


def stereo_covariance(points: NDArray, eye: NDArray, base_std: float, per_m2: float) -> NDArray:
    """(n, 3, 3): ``base_std`` across the ray from ``eye``, plus ``per_m2 * range^2`` along it."""
    ray = points - eye
    distance = np.linalg.norm(ray, axis=1)
    unit = ray / np.maximum(distance, 1e-9)[:, None]
    along = (base_std + per_m2 * distance**2) ** 2 - base_std**2
    return base_std**2 * np.eye(3) + along[:, None, None] * unit[:, :, None] * unit[:, None, :]


def touches_volume(bbox_min: NDArray, bbox_max: NDArray, pose: NDArray, volume: VolumeConfig, margin: float) -> NDArray:
    """(n,) whether a world-frame box reaches within ``margin`` of the volume's sides, near or far end.

    The road below and the sky above do not cut obstacles sideways, so only x and y limits count.
    """
    corners = bbox_min[:, None, :] + _CORNERS[None] * (bbox_max - bbox_min)[:, None, :]
    to_vehicle = invert(pose)
    local = corners @ to_vehicle[0:3, 0:3].T + to_vehicle[0:3, 3]
    x, y = local[..., 0], local[..., 1]
    return (
        (x.min(axis=1) <= volume.x_min + margin)
        | (x.max(axis=1) >= volume.x_max - margin)
        | (np.abs(y).max(axis=1) >= volume.y_half - margin)
    )


def visibility_covariance(extent: NDArray, prev_extent: NDArray, cut: NDArray) -> NDArray:
    """(n, 3, 3) diagonal: extent change per axis, or the whole extent for a cut cluster."""
    std = np.abs(extent - prev_extent)
    std = np.where(cut[:, None], np.maximum(std, extent), std)
    out = np.zeros((len(std), 3, 3))
    idx = np.arange(3)
    out[:, idx, idx] = std**2
    return out
