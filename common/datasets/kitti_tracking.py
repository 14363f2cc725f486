"""KITTI tracking training sequences: colour stereo, OXTS ego motion and label_02 objects.

Layout: ``training/{image_02,image_03}/NNNN/NNNNNN.png``, ``label_02/NNNN.txt``,
``oxts/NNNN.txt`` (one packet per frame) and ``calib/NNNN.txt``. The label and OXTS files cover
the whole sequence; only frames with images are imported. Tracking has no timestamps file, so
frames are stamped FRAME_NS apart: not the nominal 10 Hz, but the interval the raw drives' own
timestamps show (the Velodyne triggers the cameras). Raw drive 0009, which is tracking sequence
0001, has a median of 103.40 ms; at 100 ms every speed measured from positions came out 3.4 %
too high, and a speed sensor integrated over the frames 3.4 % too short.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from common.datasets import kitti_calib, oxts, velodyne
from common.datasets.export import recording_info, write_frames
from common.datasets.images import image_size, paired_files
from common.datasets.kitti_labels import frame_truth, read_labels
from common.datasets.sequence import StereoSequence, frame_numbers
from common.errors import InputError
from common.messages import GroundTruthObjects, Message

F64 = npt.NDArray[np.float64]

FRAME_NS = 103_400_000


@dataclass
class TrackingSequence:
    sequence: StereoSequence
    truth: dict[int, GroundTruthObjects]


def load(training: Path, sequence: str, max_frames: int | None = None) -> TrackingSequence:
    """Calibration, true poses and labelled objects of one sequence; images are read when written."""
    rig = kitti_calib.load_tracking(training / "calib" / f"{sequence}.txt")
    pairs = paired_files(training / "image_02" / sequence, training / "image_03" / sequence)[:max_frames]
    frames = frame_numbers(pairs)
    oxts_file = training / "oxts" / f"{sequence}.txt"
    packets = oxts.read_packet_lines(oxts_file)
    if len(packets) <= max(frames):
        raise InputError(f"{oxts_file}: {len(packets)} packets, frame {max(frames)} has images")
    packets = packets[frames]
    cam_to_vehicle = rig.cam_to_vehicle()
    poses = oxts.vehicle_poses(packets, rig.imu_to_cam2(), cam_to_vehicle)
    velocities = oxts.world_velocities(packets, poses, cam_to_vehicle @ rig.imu_to_cam2())
    stamps = [frame * FRAME_NS for frame in frames]
    stereo = StereoSequence(frames, stamps, pairs, rig.calibration(*image_size(pairs[0][0])), poses, velocities,
                            oxts.vehicle_motion(packets))
    labels = read_labels(training / "label_02" / f"{sequence}.txt")
    truth = frame_truth(labels, frames, stamps, poses, cam_to_vehicle @ rig.cam0_to_cam2())
    return TrackingSequence(stereo, truth)


def import_sequence(training: Path, sequence: str, out: Path, max_frames: int | None = None) -> int:
    """Write one tracking sequence to ``out``; returns the frames written."""
    loaded = load(training, sequence, max_frames)
    seq = loaded.sequence
    rig = kitti_calib.load_tracking(training / "calib" / f"{sequence}.txt")
    scans = {f: training / "velodyne" / sequence / f"{f:06d}.bin" for f in seq.frames}
    lidar = velodyne.ScanTruth(scans, dict(zip(seq.frames, seq.stamps, strict=True)), rig.velo_to_cam2, seq.calib)

    def truth(frame: int) -> list[Message]:
        return [loaded.truth[frame], *lidar.messages(frame)]

    info = recording_info("kitti-tracking", sequence, len(seq.frames), seq.calib, lidar_frames=lidar.frames,
                          frame_rate_hz=1e9 / FRAME_NS)
    return write_frames(out, info, seq.messages(truth), f"import tracking {sequence}")
