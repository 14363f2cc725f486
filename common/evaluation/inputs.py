"""Everything evaluation needs from a run recording, read in one pass and joined by frame id.

A recording can hold hundreds of disparity images; the D1 figures are computed as soon as both
the estimate and the truth of a frame have been read, so at most a few images are in memory.
Clusters keep only their boxes and centroids, not their voxels.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from common.config import VolumeConfig
from common.errors import RecordingError
from common.evaluation.edges import EdgeCounts, dense, edge_counts
from common.evaluation.stereo import d1_frame
from common.messages import (
    Calibration,
    Clusters,
    Disparity,
    EgoMotion,
    GroundTruthDisparity,
    GroundTruthEgo,
    GroundTruthObjects,
    Message,
    Obstacles,
    Timing,
    merged_trail,
)
from common.recording import open_recording

F64 = npt.NDArray[np.float64]

#: KITTI's longer baseline and focal length see farther (EVALUATION.md).
KITTI_VOLUME = VolumeConfig(x_min=0.0, x_max=45.0, y_half=10.0, z_min=0.0, z_max=3.5)

TOPICS: tuple[str, ...] = (
    "groundtruth/ego",
    "groundtruth/objects",
    "groundtruth/disparity",
    "stereo_depth/disparity",
    "odometry/ego",
    "voxel_mapper/clusters",
    "tracker/obstacles",
)


@dataclass(frozen=True)
class ClusterBox:
    """A voxel cluster reduced to what segmentation scores: world-frame centroid and box."""

    centroid: F64
    bbox_min: F64
    bbox_max: F64


@dataclass
class FrameClusters:
    ego_pose: F64
    boxes: list[ClusterBox]


@dataclass
class RunInputs:
    """A run recording's ground truth and pipeline outputs, keyed by frame id."""

    path: Path
    info: dict[str, Any]
    volume: VolumeConfig
    calib: Calibration | None
    gt_complete: bool
    frame_ids: set[int] = field(default_factory=set)
    true_poses: dict[int, F64] = field(default_factory=dict)
    truth: dict[int, GroundTruthObjects] = field(default_factory=dict)
    est_poses: dict[int, EgoMotion] = field(default_factory=dict)
    obstacles: dict[int, Obstacles] = field(default_factory=dict)
    clusters: dict[int, FrameClusters] = field(default_factory=dict)
    stereo: dict[int, dict[str, float | None]] = field(default_factory=dict)
    edges: EdgeCounts = field(default_factory=EdgeCounts)  # beside depth steps, frames with dense truth
    trails: dict[int, list[Timing]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    decode_errors: int = 0
    truncated: RecordingError | None = None


def volume_of(config: dict[str, Any] | None, info: dict[str, Any]) -> VolumeConfig:
    """The configured volume: the run's configuration, else the recording's facts, else a default."""
    for source in ((config or {}).get("volume"), info.get("volume")):
        if isinstance(source, dict):
            known = {k: float(v) for k, v in source.items() if k in VolumeConfig.__dataclass_fields__}
            return VolumeConfig(**known)
    if str(info.get("source", "")).startswith("kitti"):
        return KITTI_VOLUME
    return VolumeConfig()


def calibration_of(info: dict[str, Any]) -> Calibration | None:
    """The recording's calibration from its facts, if they carry one."""
    calib = info.get("calib")
    if not isinstance(calib, dict):
        return None
    try:
        return Calibration(
            fx=float(calib["fx"]),
            fy=float(calib["fy"]),
            cx=float(calib["cx"]),
            cy=float(calib["cy"]),
            baseline=float(calib["baseline"]),
            width=int(calib["width"]),
            height=int(calib["height"]),
            cam_to_vehicle=np.asarray(calib.get("cam_to_vehicle", np.eye(4)), dtype=np.float64).reshape(4, 4),
        )
    except (KeyError, TypeError, ValueError):
        return None


def cluster_boxes(msg: Clusters) -> FrameClusters:
    """What segmentation scores of a Clusters message (also for clusters remade in memory, scripts/sweep_tracker.py)."""
    boxes = [
        ClusterBox(np.array(c.centroid, dtype=np.float64), np.array(c.bbox_min), np.array(c.bbox_max))
        for c in msg.clusters
    ]
    return FrameClusters(np.array(msg.ego_pose, dtype=np.float64), boxes)


#: disparity images kept while waiting for their pair; a recording writes a frame's estimate and
#: truth close together, and most estimates have no truth at all (synthetic truth every n-th frame).
PENDING_IMAGES: int = 32


class _Reader:
    """Dispatches each decoded message to where it belongs in :class:`RunInputs`."""

    def __init__(self, run: RunInputs) -> None:
        self.run = run
        self.pending_est: dict[int, Any] = {}
        self.pending_truth: dict[int, Any] = {}

    def add(self, msg: Message) -> None:
        run, fid = self.run, msg.frame_id
        run.frame_ids.add(fid)
        if msg.timing:
            run.trails[fid] = merged_trail(Message(frame_id=fid, stamp_ns=0, timing=run.trails.get(fid, [])), msg)
        if isinstance(msg, GroundTruthEgo):
            run.true_poses[fid] = np.array(msg.pose, dtype=np.float64)
        elif isinstance(msg, GroundTruthObjects):
            run.truth[fid] = msg
            run.gt_complete = run.gt_complete or msg.gt_complete
        elif isinstance(msg, EgoMotion):
            run.est_poses[fid] = msg
        elif isinstance(msg, Obstacles):
            run.obstacles[fid] = msg
        elif isinstance(msg, Clusters):
            run.clusters[fid] = cluster_boxes(msg)
        elif isinstance(msg, Disparity):
            if run.calib is None:
                run.calib = msg.calib
            self.pending_est[fid] = msg.disparity
            self._score_stereo(fid)
        elif isinstance(msg, GroundTruthDisparity):
            self.pending_truth[fid] = msg.disparity
            self._score_stereo(fid)

    def _score_stereo(self, fid: int) -> None:
        for pending in (self.pending_est, self.pending_truth):
            while len(pending) > PENDING_IMAGES:
                del pending[min(pending)]
        if fid in self.pending_est and fid in self.pending_truth:
            est, truth = self.pending_est.pop(fid), self.pending_truth.pop(fid)
            if est.shape == truth.shape:
                self.run.stereo[fid] = d1_frame(est, truth)
                if dense(truth):
                    self.run.edges.add(edge_counts(est, truth))
            else:
                note = f"frame {fid}: disparity {est.shape} and its truth {truth.shape} differ; not scored"
                self.run.notes.append(note)


def read_inputs(path: str | Path, allow_truncated: bool = False) -> RunInputs:
    """Read a run recording; a damaged one raises :class:`RecordingError` unless allowed."""
    reader = open_recording(path)
    info = reader.info()
    config = reader.config_dict()
    if reader.truncated is not None and not allow_truncated:
        raise reader.truncated
    run = RunInputs(
        path=Path(path),
        info=info,
        volume=volume_of(config, info),
        calib=calibration_of(info),
        gt_complete=bool(info.get("gt_complete", False)),
    )
    dispatch = _Reader(run)
    for _, msg in reader.messages(topics=TOPICS):
        dispatch.add(msg)
    run.decode_errors = reader.decode_errors
    run.truncated = reader.truncated
    if run.truncated is not None and not allow_truncated:
        raise run.truncated
    return run
