"""KITTI raw ``tracklet_labels.xml``: annotated 3-D boxes in the Velodyne frame, per frame.

A tracklet is one object (its index in the file is its track id) with a fixed size and a pose
per frame from ``first_frame`` on: the bottom centre (tx, ty, tz) and heading rz in the Velodyne
frame, plus truncation and occlusion states. The states map onto the tracking labels' fields so
EVALUATION.md's visibility rule (in the image, at most partly occluded) applies unchanged:
truncation IN_IMAGE -> 0.0, TRUNCATED / OUT_IMAGE / BEHIND_IMAGE -> 1.0, UNSET -> unknown.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from common.datasets.kitti_labels import fit_motion
from common.errors import InputError
from common.messages import GroundTruthObject, GroundTruthObjects

F64 = npt.NDArray[np.float64]

TRUNCATION_IN_IMAGE, TRUNCATION_UNSET = 0, 99


@dataclass(frozen=True)
class TrackletPose:
    frame: int
    bottom: tuple[float, float, float]  # Velodyne frame
    yaw: float  # rz, about the Velodyne's up axis
    truncation: int
    occlusion: int


@dataclass(frozen=True)
class Tracklet:
    id: int
    cls: str
    hwl: tuple[float, float, float]
    poses: list[TrackletPose]


def _number(item: ET.Element, tag: str, path: Path) -> float:
    node = item.find(tag)
    try:
        return float(node.text or "") if node is not None else float("nan")
    except ValueError:
        raise InputError(f"{path}: <{tag}> holds {node.text!r}, not a number") from None


def read_tracklets(path: Path) -> list[Tracklet]:
    """Every tracklet of the file, in file order."""
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise InputError(f"{path}: not a readable tracklet file ({exc})") from None
    container = root.find("tracklets")
    if container is None:
        raise InputError(f"{path}: no <tracklets> element")
    out = []
    for index, item in enumerate(container.findall("item")):
        first = int(_number(item, "first_frame", path))
        poses = [
            TrackletPose(
                first + k, (_number(p, "tx", path), _number(p, "ty", path), _number(p, "tz", path)),
                _number(p, "rz", path), int(_number(p, "truncation", path)), int(_number(p, "occlusion", path)),
            )
            for k, p in enumerate(item.findall("poses/item"))
        ]
        hwl = (_number(item, "h", path), _number(item, "w", path), _number(item, "l", path))
        if not np.all(np.isfinite(hwl)):
            raise InputError(f"{path}: tracklet {index} has no finite h, w, l")
        out.append(Tracklet(index, (item.findtext("objectType") or "Misc").strip(), hwl, poses))
    return out


def world_object(track: Tracklet, pose: TrackletPose, velo_to_vehicle: F64, vehicle_pose: F64) -> GroundTruthObject:
    h, w, length = track.hwl
    to_world = vehicle_pose @ velo_to_vehicle
    centre = to_world @ np.array([pose.bottom[0], pose.bottom[1], pose.bottom[2] + h / 2.0, 1.0])
    heading = to_world[:3, :3] @ np.array([np.cos(pose.yaw), np.sin(pose.yaw), 0.0])
    truncated = -1.0 if pose.truncation == TRUNCATION_UNSET else float(pose.truncation != TRUNCATION_IN_IMAGE)
    return GroundTruthObject(
        id=track.id, cls=track.cls, center=centre[:3], size=np.array([length, w, h]),
        yaw=float(np.arctan2(heading[1], heading[0])), velocity=np.zeros(3), moving=False,
        truncated=truncated, occluded=pose.occlusion,
    )


def frame_truth(tracks: Sequence[Tracklet], frames: Sequence[int], stamps: Sequence[int],
                poses: Sequence[F64], velo_to_vehicle: F64) -> dict[int, GroundTruthObjects]:
    """Objects of the given frames in the world frame, velocities fitted as for tracking labels."""
    index = {frame: k for k, frame in enumerate(frames)}
    objects: dict[int, list[GroundTruthObject]] = {frame: [] for frame in frames}
    for track in tracks:
        for pose in track.poses:
            if pose.frame in index:
                objects[pose.frame].append(world_object(track, pose, velo_to_vehicle, poses[index[pose.frame]]))
    truth = {frame: GroundTruthObjects(frame_id=frame, stamp_ns=stamps[index[frame]], objects=objs)
             for frame, objs in objects.items()}
    fit_motion(truth)
    return truth
