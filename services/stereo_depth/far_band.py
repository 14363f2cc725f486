"""Where in the image far objects are seen, and how a pass widened over it is merged in.

A pixel of disparity is worth range ** 2 / (fx * baseline) metres: 0.9 m at 15 m on the synthetic
rig, 0.1 m at 5 m. Matching the pair widened (``stereo.upsample_x``) pays where it is worth
metres, so with ``stereo.upsample_beyond_m`` set only the box of rows and columns where the
volume of interest beyond that range projects is widened, over the short range of disparities it
needs, and the unwidened disparity is kept where the widened pass has none, unless it stands in
front of the widened values beside it. Measured (docs/results/voxel.md, "Session 65"): on
synthetic urban the widened far field alone gives what widening the whole pair gave, and keeping
the unwidened values in its holes keeps KITTI raw's density, which widening the whole pair lost.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

from common.config import VolumeConfig
from common.messages import Calibration
from services.stereo_depth.sgbm import DisparityMap, round_up_16

#: rows matched above and below the band, and columns right of it, thrown away: SGM's paths start there.
MARGIN_PX: int = 16
#: disparities the widened pass searches past the range's own: on Middlebury (fx * baseline 150 px m,
#: 10 px at 15 m) a search of 16 left pixels of 12-16 px beyond its reach, read wrongly short of
#: it (D1-est 3.6 -> 4.1 %); with 8, 3.75 %.
SEARCH_MARGIN_PX: float = 8.0
#: widened values this close to the end of the band's range are not trusted (as matcher.NEAR_MARGIN_PX).
REACH_MARGIN_PX: float = 4.0
#: a hole in the widened rows keeps the unwidened value only if it is no nearer than the widened
#: values within this many columns either side, plus ``HOLE_STEP_PX``: beside a thin pole the hole
#: is where the unwidened pass drew the pole's disparity onto the wall behind it.
HOLE_REACH_PX: int = 8
HOLE_STEP_PX: float = 1.0


class FarRegion(NamedTuple):
    """Where the volume beyond a range is seen in the left image (rows ``top`` to ``bottom``,
    columns ``left`` to ``right``, each past the last), and the disparities to search there."""

    top: int
    bottom: int
    left: int
    right: int
    reach_px: int


def far_region(calib: Calibration, volume: VolumeConfig, beyond_m: float) -> FarRegion | None:
    """The box around where the volume of interest beyond ``beyond_m`` (m ahead) projects in the
    left image; None where none of it does. On the synthetic rig at 15 m: rows 152-309 of 480, every
    column; on KITTI's, rows 83-254 of 375 and columns 227-1015 of 1242 (the volume's 8.2 m either side)."""
    vehicle_to_camera = np.linalg.inv(np.asarray(calib.cam_to_vehicle, dtype=np.float64))
    corners = np.array(
        [(x, y, z, 1.0) for x in (beyond_m, max(volume.x_max, beyond_m)) for y in (-volume.y_half, volume.y_half)
         for z in (volume.z_min, volume.z_max)]
    )  # fmt: skip
    seen = (vehicle_to_camera @ corners.T).T
    seen = seen[seen[:, 2] > 0.1]  # in front of the camera
    if len(seen) == 0:
        return None
    rows = calib.fy * seen[:, 1] / seen[:, 2] + calib.cy
    cols = calib.fx * seen[:, 0] / seen[:, 2] + calib.cx
    top, bottom = (max(0, min(int(v), calib.height)) for v in (np.floor(rows.min()), np.ceil(rows.max()) + 1))
    left, right = (max(0, min(int(v), calib.width)) for v in (np.floor(cols.min()), np.ceil(cols.max()) + 1))
    if bottom <= top or right <= left:
        return None
    return FarRegion(top, bottom, left, right, far_reach_px(calib, beyond_m))


def far_reach_px(calib: Calibration, beyond_m: float) -> int:
    """Disparities (full-resolution pixels, a multiple of 16) the widened pass searches: all of the
    range beyond ``beyond_m``, and ``SEARCH_MARGIN_PX`` more."""
    return round_up_16(calib.fx * calib.baseline / beyond_m + SEARCH_MARGIN_PX)


def merged(disparity: DisparityMap, widened: DisparityMap, top: int, left: int, reach_px: int) -> DisparityMap:
    """``disparity`` with the widened pass's values (``widened``: its block from row ``top``, column
    ``left``) where it has one short of its reach and ``disparity`` does not put the pixel nearer
    than that (in a hole of ``disparity``, only where ``disparity`` has a value short of that reach
    within ``HOLE_REACH_PX`` columns); in the widened pass's holes, ``disparity``'s value only where
    it is not in front of the widened values beside it."""
    out = disparity.copy()
    block = (slice(top, top + widened.shape[0]), slice(left, left + widened.shape[1]))
    near = reach_px - REACH_MARGIN_PX
    before = disparity[block]
    with np.errstate(invalid="ignore"):  # NaN: no value, on either side
        take = (widened < near) & ~(before >= near)
        # a hole is filled only beside the far field: a wall 4 m ahead, out of the widened pass's reach,
        # is matched in its holes and along the image's left edge to far disparities that pass its checks
        window = np.ones((1, 2 * HOLE_REACH_PX + 1), np.uint8)
        far_beside = cv2.dilate((before < near).astype(np.uint8), window) > 0
        take &= ~np.isnan(before) | far_beside
        beside = np.where(take, widened, np.float32(np.inf)).astype(np.float32)
        nearest = cv2.erode(beside, window, borderType=cv2.BORDER_REPLICATE)
        keep = (before >= near) | (before <= nearest + HOLE_STEP_PX)
    out[block] = np.where(take, widened, np.where(keep, before, np.float32(np.nan)))
    return out
