"""Velodyne scans projected into the left rectified image: KITTI's kind of stereo ground truth.

KITTI's own stereo benchmark builds its truth the same way, so D1 measured against it is
comparable in kind. EVALUATION.md fixes the rules: coordinates rounded to the nearest pixel,
depth > 0, the nearest point wins a pixel, disparity = fx * baseline / depth; pixels without a
point are NaN (``sparse`` truth).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.messages import Calibration, GroundTruthDisparity

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]


def read_scan(path: Path) -> F32:
    """A ``velodyne_points/data/*.bin`` scan: float32 x, y, z, reflectance per point."""
    try:
        raw = np.fromfile(path, dtype=np.float32)
    except OSError as exc:
        raise InputError(f"{path}: cannot read Velodyne scan ({exc.strerror})") from None
    if raw.size % 4:
        raise InputError(f"{path}: {raw.size} floats is not a whole number of (x, y, z, reflectance) points")
    return raw.reshape(-1, 4)


def scan_disparity(points: F32, velo_to_cam: F64, calib: Calibration) -> F32:
    """Sparse left-image disparity (NaN where no point lands) of points in the Velodyne frame.

    ``velo_to_cam`` maps Velodyne coordinates into the left rectified colour camera.
    """
    xyz = points[:, :3].astype(np.float64) @ velo_to_cam[:3, :3].T + velo_to_cam[:3, 3]
    xyz = xyz[xyz[:, 2] > 0.0]
    depth = xyz[:, 2]
    u = np.rint(calib.fx * xyz[:, 0] / depth + calib.cx).astype(np.int64)
    v = np.rint(calib.fy * xyz[:, 1] / depth + calib.cy).astype(np.int64)
    inside = (u >= 0) & (u < calib.width) & (v >= 0) & (v < calib.height)
    pixel, depth = v[inside] * calib.width + u[inside], depth[inside]
    order = np.lexsort((depth, pixel))  # by pixel, nearest first within a pixel
    pixel, depth = pixel[order], depth[order]
    first = np.concatenate([[True], pixel[1:] != pixel[:-1]]) if pixel.size else np.zeros(0, bool)
    disparity = np.full(calib.width * calib.height, np.nan, dtype=np.float32)
    disparity[pixel[first]] = (calib.fx * calib.baseline / depth[first]).astype(np.float32)
    return disparity.reshape(calib.height, calib.width)



class ScanTruth:
    """The sparse true disparity of every frame that has a scan (the KITTI samples have a few)."""

    def __init__(self, scans: dict[int, Path], stamps: dict[int, int], velo_to_cam: Callable[[], F64],
                 calib: Calibration) -> None:
        self.scans = {frame: path for frame, path in scans.items() if path.is_file()}
        self.stamps = stamps
        self.calib = calib
        # only asked for when there is a scan: a calibration without a Velodyne mount is fine otherwise
        self.velo_to_cam = velo_to_cam() if self.scans else np.eye(4)

    @property
    def frames(self) -> list[int]:
        return sorted(self.scans)

    def messages(self, frame: int) -> list[GroundTruthDisparity]:
        if frame not in self.scans:
            return []
        disparity = scan_disparity(read_scan(self.scans[frame]), self.velo_to_cam, self.calib)
        return [GroundTruthDisparity(frame_id=frame, stamp_ns=self.stamps[frame], disparity=disparity, sparse=True)]
