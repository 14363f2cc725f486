"""KITTI tracking labels (label_02) as per-frame ground-truth objects in the world frame.

A label row places a box by its bottom centre, size (h, w, l) and heading rotation_y in the
rectified camera 0 frame of its frame. Stereovox compares objects by their geometric centre in
the world frame, so each row is raised by half its height, carried into the left colour camera,
the vehicle frame and the world with the frame's true pose. The true velocity is what
EVALUATION.md defines for real data: the least-squares slope of the world position over +-5
frames (the evaluation's own fit, reused so the stored ``moving`` flag agrees with the score).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.evaluation.matching import MOVING_MPS
from common.evaluation.velocity import fit_velocities
from common.messages import GroundTruthObject, GroundTruthObjects

F64 = npt.NDArray[np.float64]

DONTCARE = "DontCare"
#: values per row: frame, id, type, truncated, occluded, alpha, 2-D box (4), h w l, x y z, rotation_y.
COLUMNS: int = 17


@dataclass(frozen=True)
class LabelRow:
    frame: int
    track: int
    cls: str
    truncated: float
    occluded: int
    box: tuple[float, float, float, float]  # x1, y1, x2, y2 in the left image
    hwl: tuple[float, float, float]
    bottom: tuple[float, float, float]  # bottom centre, rectified camera 0
    rotation_y: float


def parse_row(line: str, path: Path, number: int) -> LabelRow:
    parts = line.split()
    if len(parts) not in (COLUMNS, COLUMNS + 1):  # results files add a score
        raise InputError(f"{path}:{number}: label row needs {COLUMNS} values, has {len(parts)}")
    try:
        nums = [float(v) for v in parts[3:COLUMNS]]
        frame, track = int(parts[0]), int(parts[1])
    except ValueError:
        raise InputError(f"{path}:{number}: label row holds a value that is not a number") from None
    if not np.all(np.isfinite(nums)):
        raise InputError(f"{path}:{number}: label row holds a non-finite value")
    return LabelRow(frame, track, parts[2], nums[0], int(nums[1]), (nums[3], nums[4], nums[5], nums[6]),
                    (nums[7], nums[8], nums[9]), (nums[10], nums[11], nums[12]), nums[13])


def read_labels(path: Path) -> dict[int, list[LabelRow]]:
    """Every row of a label_02 file, by frame."""
    if not path.is_file():
        raise InputError(f"{path}: label file missing")
    rows: dict[int, list[LabelRow]] = {}
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if line.strip():
            row = parse_row(line, path, number)
            rows.setdefault(row.frame, []).append(row)
    return rows


def world_object(row: LabelRow, cam0_to_vehicle: F64, pose: F64) -> GroundTruthObject:
    """A labelled box at its geometric centre, heading and size in the world frame (velocity unset)."""
    h, w, length = row.hwl
    centre_cam = np.array([row.bottom[0], row.bottom[1] - h / 2.0, row.bottom[2], 1.0])  # camera y is down
    to_world = pose @ cam0_to_vehicle
    heading_cam = np.array([np.cos(row.rotation_y), 0.0, -np.sin(row.rotation_y)])  # the box's length axis
    heading = to_world[:3, :3] @ heading_cam
    return GroundTruthObject(
        id=row.track, cls=row.cls, center=(to_world @ centre_cam)[:3], size=np.array([length, w, h]),
        yaw=float(np.arctan2(heading[1], heading[0])), velocity=np.zeros(3), moving=False,
        truncated=row.truncated, occluded=row.occluded,
    )


def dontcare_boxes(rows: Sequence[LabelRow]) -> npt.NDArray[np.float32]:
    boxes = [row.box for row in rows if row.cls == DONTCARE]
    return np.array(boxes, dtype=np.float32).reshape(-1, 4)


def frame_truth(rows: Mapping[int, list[LabelRow]], frames: Sequence[int], stamps: Sequence[int],
                poses: Sequence[F64], cam0_to_vehicle: F64) -> dict[int, GroundTruthObjects]:
    """Ground-truth objects of the given frames, with velocities fitted over those same frames."""
    truth = {}
    for frame, stamp, pose in zip(frames, stamps, poses, strict=True):
        labelled = rows.get(frame, [])
        objects = [world_object(r, cam0_to_vehicle, pose) for r in labelled if r.cls != DONTCARE]
        truth[frame] = GroundTruthObjects(frame_id=frame, stamp_ns=stamp, objects=objects,
                                          dontcare=dontcare_boxes(labelled), gt_complete=False)
    fit_motion(truth)
    return truth


def fit_motion(truth: Mapping[int, GroundTruthObjects]) -> None:
    """Velocities as the evaluation fits them, and ``moving`` from the evaluation's threshold."""
    fit_velocities(truth)
    for msg in truth.values():
        for obj in msg.objects:
            obj.moving = bool(np.linalg.norm(obj.velocity) >= MOVING_MPS)
