"""Bringing detections and ground truth into one vehicle frame and pairing them, frame by frame.

Detections are placed with the pose the pipeline *estimated* and ground truth with the *true*
pose, so odometry drift does not show up as detection error (EVALUATION.md). Pairing is a
Hungarian assignment on centroid distance seen from above, restricted to pairs whose detection
centroid lies inside the object's box grown by a margin: a detection far from every object stays
unmatched however the assignment would like to use it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from common.config import VolumeConfig
from common.geometry import invert, yaw_of
from common.messages import Calibration, GroundTruthObject, Obstacle

F64 = npt.NDArray[np.float64]

#: detection centroid inside the object's box grown by this much (m) to be a candidate pair.
MATCH_MARGIN_M: float = 0.5
#: speed classes (m/s): moving at or above, stationary below; in between is ignored.
MOVING_MPS: float = 1.0
STATIONARY_MPS: float = 0.3
#: synthetic visibility: share of the projected area visible, and visible pixels.
MIN_VISIBLE_FRACTION: float = 0.5
MIN_VISIBLE_PIXELS: int = 50
#: KITTI visibility: fully inside the image and at most partly occluded.
MAX_OCCLUSION: int = 1

_FORBIDDEN = 1e9


@dataclass(frozen=True)
class TruthView:
    """A ground-truth object in the vehicle frame of one frame, and how it is scored."""

    id: int
    center: F64
    size: F64  # length (along yaw), width, height
    yaw: float
    velocity: F64
    counted: bool  # centre inside the volume and visible
    motion: str  # "moving" | "stationary" | "between"


@dataclass(frozen=True)
class DetectionView:
    """A scored (tracked) obstacle in the vehicle frame of one frame."""

    id: int
    centroid: F64
    velocity: F64
    moving: bool
    ignored: bool  # outside the volume (x, y) or projecting into a DontCare region, if unmatched


@dataclass
class FrameMatch:
    """One frame's truths, detections and the pairs between them (detection -> truth index)."""

    frame_id: int
    truths: list[TruthView]
    detections: list[DetectionView]
    pairs: dict[int, int]
    near: list[list[int]] = field(default_factory=list)  # per detection: truths whose grown box holds it

    def truth_of(self, det: int) -> TruthView | None:
        index = self.pairs.get(det)
        return None if index is None else self.truths[index]

    def detection_of(self) -> dict[int, int]:
        """Truth index -> detection index."""
        return {t: d for d, t in self.pairs.items()}


def motion_class(speed: float) -> str:
    if speed >= MOVING_MPS:
        return "moving"
    if speed < STATIONARY_MPS:
        return "stationary"
    return "between"


def visible(obj: GroundTruthObject) -> bool:
    """The data's own visibility convention; a field left unknown (-1) does not exclude."""
    if obj.visible_fraction >= 0.0 or obj.visible_pixels >= 0:
        return obj.visible_fraction >= MIN_VISIBLE_FRACTION and obj.visible_pixels >= MIN_VISIBLE_PIXELS
    truncated_ok = obj.truncated < 0.0 or obj.truncated == 0.0
    occluded_ok = obj.occluded < 0 or obj.occluded <= MAX_OCCLUSION
    return truncated_ok and occluded_ok


def in_volume(point: F64, volume: VolumeConfig) -> bool:
    x, y, z = (float(v) for v in point[:3])
    return volume.x_min <= x <= volume.x_max and abs(y) <= volume.y_half and volume.z_min <= z <= volume.z_max


def in_footprint(point: F64, volume: VolumeConfig) -> bool:
    """Inside the volume seen from above."""
    return volume.x_min <= float(point[0]) <= volume.x_max and abs(float(point[1])) <= volume.y_half


def truth_in_vehicle(obj: GroundTruthObject, true_pose: F64, volume: VolumeConfig) -> TruthView:
    """A world-frame object seen from the vehicle's true pose."""
    to_vehicle = invert(true_pose)
    center = to_vehicle[:3, :3] @ np.asarray(obj.center, dtype=np.float64) + to_vehicle[:3, 3]
    velocity = to_vehicle[:3, :3] @ np.asarray(obj.velocity, dtype=np.float64)
    return TruthView(
        id=int(obj.id),
        center=center,
        size=np.asarray(obj.size, dtype=np.float64),
        yaw=float(obj.yaw) - yaw_of(true_pose),
        velocity=velocity,
        counted=in_volume(center, volume) and visible(obj),
        motion=motion_class(float(np.linalg.norm(obj.velocity))),
    )


def in_dontcare(point: F64, calib: Calibration | None, boxes: npt.NDArray[np.floating]) -> bool:
    """Whether a vehicle-frame point projects into any DontCare image box (x1, y1, x2, y2)."""
    if calib is None or len(boxes) == 0:
        return False
    cam = invert(np.asarray(calib.cam_to_vehicle, dtype=np.float64))
    x, y, z = cam[:3, :3] @ point[:3] + cam[:3, 3]
    if z <= 0.0:
        return False
    u, v = calib.fx * x / z + calib.cx, calib.fy * y / z + calib.cy
    b = np.asarray(boxes, dtype=np.float64)
    return bool(np.any((b[:, 0] <= u) & (u <= b[:, 2]) & (b[:, 1] <= v) & (v <= b[:, 3])))


def detection_in_vehicle(
    obs: Obstacle,
    est_pose: F64,
    volume: VolumeConfig,
    calib: Calibration | None,
    dontcare: npt.NDArray[np.floating],
) -> DetectionView:
    """A world-frame obstacle seen from the pose the pipeline estimated for that frame.

    Only x and y decide whether it is outside the volume: a centroid's height depends on which
    part of an object the cameras saw, its place on the ground does not.
    """
    to_vehicle = invert(est_pose)
    centroid = to_vehicle[:3, :3] @ np.asarray(obs.centroid, dtype=np.float64) + to_vehicle[:3, 3]
    velocity = to_vehicle[:3, :3] @ np.asarray(obs.velocity, dtype=np.float64)
    return DetectionView(
        id=int(obs.id),
        centroid=centroid,
        velocity=velocity,
        moving=bool(obs.moving),
        ignored=not in_footprint(centroid, volume) or in_dontcare(centroid, calib, dontcare),
    )


def inside_box_xy(points: F64, center: F64, size: F64, yaw: float, margin: float) -> npt.NDArray[np.bool_]:
    """Which (x, y) points fall inside an oriented box seen from above, grown by ``margin``."""
    rel = np.asarray(points, dtype=np.float64).reshape(-1, 2) - center[:2]
    c, s = np.cos(yaw), np.sin(yaw)
    along = rel[:, 0] * c + rel[:, 1] * s
    across = -rel[:, 0] * s + rel[:, 1] * c
    return (np.abs(along) <= size[0] / 2 + margin) & (np.abs(across) <= size[1] / 2 + margin)


def gate_matrix(
    detections: list[DetectionView], truths: list[TruthView], margin: float = MATCH_MARGIN_M
) -> npt.NDArray[np.bool_]:
    """(detections x truths): whether the detection centroid lies in the truth's grown box."""
    gate = np.zeros((len(detections), len(truths)), dtype=bool)
    if detections and truths:
        xy = np.array([d.centroid[:2] for d in detections])
        for j, t in enumerate(truths):
            gate[:, j] = inside_box_xy(xy, t.center, t.size, t.yaw, margin)
    return gate


def match(detections: list[DetectionView], truths: list[TruthView], margin: float = MATCH_MARGIN_M) -> dict[int, int]:
    """One-to-one pairs (detection index -> truth index) by Hungarian assignment on distance."""
    if not detections or not truths:
        return {}
    gate = gate_matrix(detections, truths, margin)
    xy = np.array([d.centroid[:2] for d in detections])
    centres = np.array([t.center[:2] for t in truths])
    distance = np.linalg.norm(xy[:, None, :] - centres[None, :, :], axis=2)
    cost = np.where(gate, distance, _FORBIDDEN)
    rows, cols = linear_sum_assignment(cost)
    return {int(r): int(c) for r, c in zip(rows, cols, strict=True) if gate[r, c]}


def frame_match(frame_id: int, truths: list[TruthView], detections: list[DetectionView]) -> FrameMatch:
    """Pairs of one frame, and for every detection the truths whose grown box holds it."""
    gate = gate_matrix(detections, truths)
    near = [[int(j) for j in np.nonzero(row)[0]] for row in gate]
    return FrameMatch(frame_id, truths, detections, match(detections, truths), near)
