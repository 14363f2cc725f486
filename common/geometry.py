"""Frames of reference and rigid transforms shared by every stage.

Vehicle frame: x forward, y left, z up, origin on the road under the left camera. Camera frame:
x right, y down, z forward. World frame: the vehicle frame at the first frame of an epoch.
Poses are 4x4 homogeneous matrices mapping local coordinates into the parent frame.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]

#: camera axes (x right, y down, z forward) expressed in vehicle axes (x forward, y left, z up).
CAMERA_TO_VEHICLE_AXES: F64 = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def make_pose(rotation: npt.ArrayLike, translation: npt.ArrayLike) -> F64:
    """A 4x4 pose from a 3x3 rotation and a translation."""
    pose = np.eye(4)
    pose[:3, :3] = np.asarray(rotation, dtype=np.float64)
    pose[:3, 3] = np.asarray(translation, dtype=np.float64)
    return pose


def invert(pose: F64) -> F64:
    """Inverse of a rigid transform without a general matrix inverse."""
    rot = pose[:3, :3]
    out = np.eye(4)
    out[:3, :3] = rot.T
    out[:3, 3] = -rot.T @ pose[:3, 3]
    return out


def transform(pose: F64, points: npt.NDArray[np.floating]) -> npt.NDArray[np.floating]:
    """Apply a pose to Nx3 points (dtype kept)."""
    pts = np.asarray(points)
    return (pts @ pose[:3, :3].T.astype(pts.dtype)) + pose[:3, 3].astype(pts.dtype)


def rot_x(angle: float) -> F64:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> F64:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> F64:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def camera_to_vehicle(height: float, pitch: float = 0.0) -> F64:
    """Left camera mounted ``height`` metres above the road, pitched down by ``pitch`` radians."""
    rotation = rot_y(pitch) @ CAMERA_TO_VEHICLE_AXES
    return make_pose(rotation, [0.0, 0.0, height])


def yaw_of(pose: F64) -> float:
    """Heading about the vertical axis of a pose's rotation."""
    return float(np.arctan2(pose[1, 0], pose[0, 0]))


def rotation_angle(rotation: F64) -> float:
    """Angle (radians) of a rotation matrix."""
    cos = (np.trace(rotation[:3, :3]) - 1.0) / 2.0
    return float(np.arccos(np.clip(cos, -1.0, 1.0)))
