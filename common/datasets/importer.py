"""``stereovox import``: KITTI (raw, tracking, odometry), Middlebury and ROS 2 bags into a recording.

Each sub-command writes one recording holding the stereo frames and every kind of ground truth
the dataset has, plus the info metadata ``process`` and ``evaluate`` read (source, frame rate,
calibration and, for KITTI, the longer volume of interest). Bad input stops the import with a
message naming the file and line, and leaves no output file.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from common.datasets import kitti_odometry, kitti_raw, kitti_tracking, middlebury, rosbag2
from common.errors import ConfigError


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, required=True, help="recording to write (.mcap)")
    parser.add_argument("--max-frames", type=int, default=None, metavar="N", help="import only the first N frames")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="dataset", required=True, metavar="DATASET")
    raw = sub.add_parser("kitti-raw", help="a raw drive: YYYY_MM_DD/YYYY_MM_DD_drive_NNNN_sync")
    raw.add_argument("drive", type=Path, help="the drive folder (calibration is read from its parent)")
    _common(raw)
    tracking = sub.add_parser("kitti-tracking", help="a tracking training sequence with its labels")
    tracking.add_argument("training", type=Path, help="the training folder (image_02, label_02, oxts, calib)")
    tracking.add_argument("--sequence", required=True, help="sequence number, e.g. 0001")
    _common(tracking)
    odometry = sub.add_parser("kitti-odometry", help="an odometry sequence with its ground-truth poses")
    odometry.add_argument("sequence", type=Path, help="the sequence folder (image_2, image_3, calib.txt, times.txt)")
    odometry.add_argument("--poses", type=Path, required=True, help="poses/NN.txt of the sequence")
    _common(odometry)
    mb = sub.add_parser("middlebury", help="Middlebury 2003 scenes (im2, im6, disp2), one frame each")
    mb.add_argument("folder", type=Path, help="a scene folder, or a folder of scene folders")
    _common(mb)
    bag = sub.add_parser("rosbag2", help="a ROS 2 bag (MCAP storage): a rectified stereo pair's image topics")
    bag.add_argument("bag", type=Path, help="the bag's .mcap file, or its rosbag2 folder")
    bag.add_argument("--left", required=True, help="left rectified image topic (sensor_msgs Image or CompressedImage)")
    bag.add_argument("--right", required=True, help="right rectified image topic")
    bag.add_argument("--left-info", default=None, help="left CameraInfo topic (default: camera_info beside --left)")
    bag.add_argument("--right-info", default=None, help="right CameraInfo topic (default: camera_info beside --right)")
    bag.add_argument("--camera-height", type=float, required=True, metavar="M",
                     help="the left camera's height above the road (m); the bag does not say")
    bag.add_argument("--pitch-deg", type=float, default=0.0, help="the rig pitched down by this much (degrees)")
    bag.add_argument("--sync-tolerance-ms", type=float, default=1.0, metavar="MS",
                     help="left and right header stamps this close are one frame")
    _common(bag)


def run(args: argparse.Namespace) -> int:
    if args.max_frames is not None and args.max_frames < 1:
        raise ConfigError(f"--max-frames must be at least 1, got {args.max_frames}")
    start = time.perf_counter()
    if args.dataset == "kitti-raw":
        frames = kitti_raw.import_drive(args.drive, args.out, args.max_frames)
    elif args.dataset == "kitti-tracking":
        frames = kitti_tracking.import_sequence(args.training, args.sequence, args.out, args.max_frames)
    elif args.dataset == "kitti-odometry":
        frames = kitti_odometry.import_sequence(args.sequence, args.poses, args.out, args.max_frames)
    elif args.dataset == "middlebury":
        frames = middlebury.import_scenes(args.folder, args.out, args.max_frames)
    else:
        topics = rosbag2.Topics.of(args.left, args.right, args.left_info, args.right_info)
        frames, unpaired = rosbag2.import_bag(args.bag, topics, args.out, args.camera_height, args.pitch_deg,
                                             args.sync_tolerance_ms, args.max_frames)
        if unpaired:
            print(f"{unpaired} images had no partner within {args.sync_tolerance_ms} ms and were left out")
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.1f} MB, {frames} frames) "
          f"in {time.perf_counter() - start:.1f} s")
    return 0
