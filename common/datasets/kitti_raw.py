"""KITTI raw drives (``YYYY_MM_DD/YYYY_MM_DD_drive_NNNN_sync``): stereo, OXTS, lidar, tracklets.

The colour pair is already rectified (image_02 left, image_03 right). Calibration lives one
folder up, in the day's ``calib_*.txt``. OXTS gives the true ego motion, Velodyne scans (where
present) the sparse true disparity, and ``tracklet_labels.xml`` (where present) the objects.
"""

from __future__ import annotations

import calendar
import time
from pathlib import Path

from common.datasets import kitti_calib, oxts, tracklets, velodyne
from common.datasets.export import recording_info, write_frames
from common.datasets.images import image_size, paired_files
from common.datasets.sequence import StereoSequence, frame_numbers
from common.errors import InputError
from common.messages import Message


def parse_stamp(text: str, path: Path, line: int) -> int:
    """``2011-09-26 13:08:24.967930880`` (UTC) to nanoseconds since the epoch."""
    whole, _, fraction = text.strip().partition(".")
    try:
        seconds = calendar.timegm(time.strptime(whole, "%Y-%m-%d %H:%M:%S"))
        nanos = int((fraction + "000000000")[:9]) if fraction else 0
    except ValueError:
        raise InputError(f"{path}:{line}: {text.strip()!r} is not a YYYY-MM-DD HH:MM:SS.fffffffff time") from None
    return seconds * 1_000_000_000 + nanos


def read_stamps(path: Path, frames: list[int]) -> list[int]:
    """Capture times of the given frames (line index = frame number)."""
    if not path.is_file():
        raise InputError(f"{path}: timestamps file missing")
    lines = path.read_text().splitlines()
    if len(lines) <= max(frames):
        raise InputError(f"{path}: {len(lines)} timestamps, frame {max(frames)} has images")
    return [parse_stamp(lines[f], path, f + 1) for f in frames]


def load(drive: Path, max_frames: int | None = None) -> StereoSequence:
    """Frames, times, calibration and OXTS poses of a drive."""
    if not drive.is_dir():
        raise InputError(f"{drive}: drive folder missing")
    rig = kitti_calib.load_raw(drive.resolve().parent)
    pairs = paired_files(drive / "image_02" / "data", drive / "image_03" / "data")[:max_frames]
    frames = frame_numbers(pairs)
    packets = oxts.read_packet_files([drive / "oxts" / "data" / f"{f:010d}.txt" for f in frames])
    cam_to_vehicle = rig.cam_to_vehicle()
    poses = oxts.vehicle_poses(packets, rig.imu_to_cam2(), cam_to_vehicle)
    velocities = oxts.world_velocities(packets, poses, cam_to_vehicle @ rig.imu_to_cam2())
    stamps = read_stamps(drive / "image_02" / "timestamps.txt", frames)
    return StereoSequence(frames, stamps, pairs, rig.calibration(*image_size(pairs[0][0])), poses, velocities,
                            oxts.vehicle_motion(packets))


def import_drive(drive: Path, out: Path, max_frames: int | None = None) -> int:
    """Write a raw drive to ``out``; returns the frames written."""
    seq = load(drive, max_frames)
    rig = kitti_calib.load_raw(drive.resolve().parent)
    scans = {f: drive / "velodyne_points" / "data" / f"{f:010d}.bin" for f in seq.frames}
    lidar = velodyne.ScanTruth(scans, dict(zip(seq.frames, seq.stamps, strict=True)), rig.velo_to_cam2, seq.calib)
    xml = drive / "tracklet_labels.xml"
    objects = tracklets.frame_truth(tracklets.read_tracklets(xml), seq.frames, seq.stamps, seq.poses or [],
                                    seq.calib.cam_to_vehicle @ rig.velo_to_cam2()) if xml.is_file() else {}

    def truth(frame: int) -> list[Message]:
        return [*([objects[frame]] if frame in objects else []), *lidar.messages(frame)]

    info = recording_info("kitti-raw", drive.name, len(seq.frames), seq.calib, lidar_frames=lidar.frames,
                          tracklets=xml.is_file())
    return write_frames(out, info, seq.messages(truth), f"import {drive.name}")
