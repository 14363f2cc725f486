"""KITTI calibration files (raw, tracking, odometry) reduced to one rectified stereo rig.

Every KITTI layout stores the same facts in a different file: the rectified projections of the
colour cameras (P2 left, P3 right), the rectifying rotation of camera 0, and the Velodyne and
IMU mounts. All three importers need the same derived transforms, so they live here once:
rectified camera 0 -> left colour camera (a pure translation, P2's fourth column through K),
Velodyne -> left colour camera, IMU -> left colour camera, and the stereovox Calibration.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.geometry import camera_to_vehicle, make_pose
from common.messages import Calibration

F64 = npt.NDArray[np.float64]

#: height of KITTI's colour cameras above the road (m), from the recording platform's drawings.
KITTI_CAMERA_HEIGHT_M: float = 1.65


@dataclass(frozen=True)
class Entry:
    """One ``key: values`` line of a calibration file and where it was read."""

    path: Path
    line: int
    text: str


def read_entries(path: Path) -> dict[str, Entry]:
    """``key: numbers`` (raw, odometry) and ``key numbers`` (tracking's R_rect) lines by key."""
    if not path.is_file():
        raise InputError(f"{path}: calibration file missing")
    entries: dict[str, Entry] = {}
    for number, line in enumerate(path.read_text(errors="replace").splitlines(), start=1):
        head, sep, rest = line.partition(":")
        if not sep or " " in head.strip():
            head, _, rest = line.strip().partition(" ")
        if head.strip():
            entries[head.strip()] = Entry(path, number, rest)
    return entries


def matrix(entries: dict[str, Entry], keys: tuple[str, ...], rows: int, cols: int, path: Path) -> F64:
    """The first of ``keys`` present, parsed as a ``rows`` x ``cols`` row-major matrix."""
    entry = next((entries[k] for k in keys if k in entries), None)
    if entry is None:
        raise InputError(f"{path}: no {' or '.join(keys)} entry")
    try:
        values = np.array(entry.text.split(), dtype=np.float64)
    except ValueError:
        raise InputError(f"{entry.path}:{entry.line}: {keys[0]} holds a value that is not a number") from None
    if values.size != rows * cols or not np.all(np.isfinite(values)):
        raise InputError(f"{entry.path}:{entry.line}: {keys[0]} needs {rows * cols} finite numbers, has {values.size}")
    return values.reshape(rows, cols)


def rigid(entries: dict[str, Entry], key: str, path: Path) -> F64:
    """A 3x4 [R|t] entry as a 4x4 pose."""
    return np.vstack([matrix(entries, (key,), 3, 4, path), [0.0, 0.0, 0.0, 1.0]])


def rt_file(path: Path) -> F64:
    """Raw's ``calib_velo_to_cam.txt`` / ``calib_imu_to_velo.txt``: separate R and T lines."""
    entries = read_entries(path)
    return make_pose(matrix(entries, ("R",), 3, 3, path), matrix(entries, ("T",), 3, 1, path).ravel())


@dataclass(frozen=True)
class KittiRig:
    """The rectified colour stereo pair and the sensor mounts around it."""

    p2: F64  # 3x4 rectified projection of the left colour camera (cam2)
    p3: F64  # 3x4 rectified projection of the right colour camera (cam3)
    rect: F64  # 4x4 rectifying rotation of camera 0 (identity when poses are already rectified)
    velo_to_cam0: F64 | None = None  # 4x4, Velodyne -> unrectified camera 0
    imu_to_velo: F64 | None = None  # 4x4, OXTS IMU -> Velodyne

    @property
    def fx(self) -> float:
        return float(self.p2[0, 0])

    @property
    def baseline(self) -> float:
        """Metres between the colour cameras, from the projections' fourth columns."""
        return float((self.p2[0, 3] - self.p3[0, 3]) / self.p2[0, 0])

    def cam0_to_cam2(self) -> F64:
        """Rectified camera 0 -> left colour camera: P2 = K [I | t], so the offset is K^-1 P2[:, 3]."""
        return make_pose(np.eye(3), np.linalg.solve(self.p2[:, :3], self.p2[:, 3]))

    def velo_to_cam2(self) -> F64:
        if self.velo_to_cam0 is None:
            raise InputError("calibration has no Velodyne -> camera transform")
        return self.cam0_to_cam2() @ self.rect @ self.velo_to_cam0

    def imu_to_cam2(self) -> F64:
        if self.imu_to_velo is None:
            raise InputError("calibration has no IMU -> Velodyne transform")
        return self.velo_to_cam2() @ self.imu_to_velo

    def cam_to_vehicle(self) -> F64:
        """Left colour camera axes on stereovox's vehicle frame, at KITTI's mounting height, no pitch."""
        return camera_to_vehicle(KITTI_CAMERA_HEIGHT_M)

    def calibration(self, width: int, height: int) -> Calibration:
        if self.fx <= 0.0 or self.baseline <= 0.0:
            raise InputError(f"calibration gives focal {self.fx} px and baseline {self.baseline} m; both must be > 0")
        return Calibration(
            fx=self.fx, fy=float(self.p2[1, 1]), cx=float(self.p2[0, 2]), cy=float(self.p2[1, 2]),
            baseline=self.baseline, width=width, height=height, cam_to_vehicle=self.cam_to_vehicle(),
        )


def calibration_info(calib: Calibration) -> dict[str, Any]:
    """The ``calib`` entry of a recording's info metadata."""
    return {"fx": calib.fx, "fy": calib.fy, "cx": calib.cx, "cy": calib.cy, "baseline": calib.baseline,
            "width": calib.width, "height": calib.height, "cam_to_vehicle": calib.cam_to_vehicle.tolist()}


def load_raw(date_dir: Path) -> KittiRig:
    """A raw drive's day folder: calib_cam_to_cam.txt, calib_velo_to_cam.txt, calib_imu_to_velo.txt."""
    cam_path = date_dir / "calib_cam_to_cam.txt"
    cam = read_entries(cam_path)
    rect = np.eye(4)
    rect[:3, :3] = matrix(cam, ("R_rect_00",), 3, 3, cam_path)
    return KittiRig(
        p2=matrix(cam, ("P_rect_02",), 3, 4, cam_path),
        p3=matrix(cam, ("P_rect_03",), 3, 4, cam_path),
        rect=rect,
        velo_to_cam0=rt_file(date_dir / "calib_velo_to_cam.txt"),
        imu_to_velo=rt_file(date_dir / "calib_imu_to_velo.txt"),
    )


def load_tracking(path: Path) -> KittiRig:
    """A tracking sequence's calib/NNNN.txt: P2, P3, R_rect, Tr_velo_cam, Tr_imu_velo."""
    entries = read_entries(path)
    rect = np.eye(4)
    rect[:3, :3] = matrix(entries, ("R_rect", "R0_rect"), 3, 3, path)
    return KittiRig(
        p2=matrix(entries, ("P2",), 3, 4, path),
        p3=matrix(entries, ("P3",), 3, 4, path),
        rect=rect,
        velo_to_cam0=rigid(entries, "Tr_velo_cam", path) if "Tr_velo_cam" in entries else None,
        imu_to_velo=rigid(entries, "Tr_imu_velo", path) if "Tr_imu_velo" in entries else None,
    )


def load_odometry(path: Path) -> KittiRig:
    """An odometry sequence's calib.txt: P2, P3 and Tr (Velodyne -> rectified camera 0)."""
    entries = read_entries(path)
    return KittiRig(
        p2=matrix(entries, ("P2",), 3, 4, path),
        p3=matrix(entries, ("P3",), 3, 4, path),
        rect=np.eye(4),
        velo_to_cam0=rigid(entries, "Tr", path) if "Tr" in entries else None,
    )
