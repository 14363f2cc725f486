"""KITTI odometry sequences: colour stereo (image_2, image_3), times.txt and ground-truth poses.

The poses file gives camera 0 (grey, rectified) of frame i in camera 0 of frame 0. Stereovox's
truth is the vehicle frame under the left colour camera, so each pose is carried to camera 2 by
the cam0 -> cam2 offset (K^-1 P2[:, 3]) and re-axed by ``cam_to_vehicle``, frame 0 the identity.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from common.datasets import kitti_calib, velodyne
from common.datasets.export import recording_info, write_frames
from common.datasets.images import image_size, paired_files
from common.datasets.sequence import F64, StereoSequence, finite_difference_velocities, frame_numbers, relative_to_first
from common.errors import InputError
from common.geometry import invert


def read_rows(path: Path, columns: int, what: str) -> list[np.ndarray]:
    """Whitespace-separated numeric rows, each with ``columns`` values; errors name file and line."""
    if not path.is_file():
        raise InputError(f"{path}: {what} file missing")
    rows = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        try:
            values = np.array(line.split(), dtype=np.float64)
        except ValueError:
            raise InputError(f"{path}:{number}: {what} line holds a value that is not a number") from None
        if values.size != columns or not np.all(np.isfinite(values)):
            raise InputError(f"{path}:{number}: {what} line needs {columns} finite numbers, has {values.size}")
        rows.append(values)
    return rows


def load(sequence: Path, poses_file: Path, max_frames: int | None = None) -> StereoSequence:
    """Frames, times, calibration and true poses of an odometry sequence."""
    rig = kitti_calib.load_odometry(sequence / "calib.txt")
    pairs = paired_files(sequence / "image_2", sequence / "image_3")[:max_frames]
    frames = frame_numbers(pairs)
    times = read_rows(sequence / "times.txt", 1, "times")
    rows = read_rows(poses_file, 12, "pose")
    for name, have in (("times.txt", len(times)), (str(poses_file), len(rows))):
        if have <= max(frames):
            raise InputError(f"{name}: {have} lines, frame {max(frames)} has images")
    stamps = [round(float(times[f][0]) * 1e9) for f in frames]
    cam0_to_vehicle = rig.cam_to_vehicle() @ rig.cam0_to_cam2()
    to_cam0 = invert(cam0_to_vehicle)
    poses: list[F64] = [cam0_to_vehicle @ np.vstack([rows[f].reshape(3, 4), [0, 0, 0, 1]]) @ to_cam0 for f in frames]
    poses = relative_to_first(poses)
    calib = rig.calibration(*image_size(pairs[0][0]))
    return StereoSequence(frames, stamps, pairs, calib, poses, finite_difference_velocities(poses, stamps))


def import_sequence(sequence: Path, poses_file: Path, out: Path, max_frames: int | None = None) -> int:
    """Write an odometry sequence to ``out``; returns the frames written."""
    seq = load(sequence, poses_file, max_frames)
    rig = kitti_calib.load_odometry(sequence / "calib.txt")
    scans = {f: sequence / "velodyne" / f"{f:06d}.bin" for f in seq.frames}
    lidar = velodyne.ScanTruth(scans, dict(zip(seq.frames, seq.stamps, strict=True)), rig.velo_to_cam2, seq.calib)
    info = recording_info("kitti-odometry", sequence.name, len(seq.frames), seq.calib, lidar_frames=lidar.frames)
    return write_frames(out, info, seq.messages(lidar.messages), f"import odometry {sequence.name}")
