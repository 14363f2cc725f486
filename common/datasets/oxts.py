"""OXTS RT3003 GPS/IMU packets to ground-truth vehicle poses and velocities.

The conversion is KITTI devkit's ``convertOxtsToPose``: a Mercator projection scaled at the
first packet's latitude gives metres east/north, the altitude is up, and roll, pitch and yaw
orient the IMU. That chain is then carried through the mounts (IMU -> Velodyne -> camera 0 ->
rectified camera 0 -> left colour camera) and onto stereovox's vehicle frame, relative to the
first frame. Verified against the VISO2-S anchor on raw drive 0009 (t_err 3.34 %).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.geometry import invert, make_pose, rot_x, rot_y, rot_z

F64 = npt.NDArray[np.float64]

#: values in one OXTS packet (dataformat.txt).
FIELDS: int = 30
#: the devkit's Earth radius for the Mercator projection (m).
EARTH_RADIUS_M: float = 6378137.0
#: columns of a packet: position/orientation and the body-frame velocities vf, vl, vu.
LAT, LON, ALT, ROLL, PITCH, YAW = range(6)
VF, VL, VU = 8, 9, 10
#: rotation rate about the upward axis of the vehicle-aligned (forward, left, up) frame, rad/s.
WU = 22


@dataclass(frozen=True)
class Source:
    """Where a packet was read: a file and its 1-based line."""

    path: Path
    line: int


def parse_packet(text: str, where: Source) -> F64:
    """One packet line; anything but 30 finite numbers names the file and line."""
    try:
        values = np.array(text.split(), dtype=np.float64)
    except ValueError:
        raise InputError(f"{where.path}:{where.line}: OXTS packet holds a value that is not a number") from None
    if values.size != FIELDS or not np.all(np.isfinite(values)):
        raise InputError(f"{where.path}:{where.line}: OXTS packet needs {FIELDS} finite numbers, has {values.size}")
    return values


def read_packet_files(paths: Sequence[Path]) -> F64:
    """Raw layout: one ``oxts/data/NNNNNNNNNN.txt`` file per frame, one line each."""
    packets = []
    for path in paths:
        try:
            text = path.read_text()
        except OSError as exc:
            raise InputError(f"{path}: cannot read OXTS packet ({exc.strerror})") from None
        packets.append(parse_packet(text.strip(), Source(path, 1)))
    return np.array(packets).reshape(-1, FIELDS)


def read_packet_lines(path: Path, count: int | None = None) -> F64:
    """Tracking layout: ``oxts/NNNN.txt`` with one packet per line (the first ``count`` lines)."""
    if not path.is_file():
        raise InputError(f"{path}: OXTS file missing")
    lines = path.read_text().splitlines()[:count]
    packets = [parse_packet(line, Source(path, n)) for n, line in enumerate(lines, start=1)]
    return np.array(packets).reshape(-1, FIELDS)


def imu_poses(packets: F64) -> list[F64]:
    """IMU -> local Mercator frame poses, relative to the first packet (devkit convention)."""
    scale = np.cos(np.radians(packets[0, LAT]))
    poses = []
    for p in packets:
        east = scale * np.radians(p[LON]) * EARTH_RADIUS_M
        north = scale * EARTH_RADIUS_M * np.log(np.tan(np.radians(90.0 + p[LAT]) / 2.0))
        rotation = rot_z(p[YAW]) @ rot_y(p[PITCH]) @ rot_x(p[ROLL])
        poses.append(make_pose(rotation, [east, north, p[ALT]]))
    first = invert(poses[0])
    return [first @ pose for pose in poses]


def vehicle_poses(packets: F64, imu_to_cam: F64, cam_to_vehicle: F64) -> list[F64]:
    """Vehicle -> world poses (world = vehicle frame at frame 0) of the camera the mounts lead to.

    The IMU's motion seen from the camera is ``M P M^-1`` with M the IMU -> camera mount; the
    vehicle frame is the camera frame re-axed by ``cam_to_vehicle`` the same way.
    """
    mount = cam_to_vehicle @ imu_to_cam
    mount_inv = np.linalg.inv(mount)  # the calibration's rotations are orthonormal to 1e-7 only
    return [mount @ pose @ mount_inv for pose in imu_poses(packets)]


def vehicle_motion(packets: F64) -> F64:
    """Per packet the forward speed (m/s) and the yaw rate (rad/s): what the INS tells the odometry."""
    return packets[:, [VF, WU]].copy()


def world_velocities(packets: F64, poses: Sequence[F64], imu_to_vehicle: F64) -> F64:
    """Velocity over ground (m/s, world frame) from the IMU's body-frame vf, vl, vu.

    The IMU frame is x forward, y left, z up; its velocity is turned into vehicle axes by the
    mount rotation and into the world by each frame's pose.
    """
    body = packets[:, [VF, VL, VU]]
    mount = imu_to_vehicle[:3, :3]
    return np.array([pose[:3, :3] @ (mount @ v) for pose, v in zip(poses, body, strict=True)])
