"""``stereovox import``: KITTI (raw, tracking, odometry) and Middlebury data into a recording.

Each sub-command writes one recording holding the stereo frames and every kind of ground truth
the dataset has, plus the info metadata ``process`` and ``evaluate`` read (source, frame rate,
calibration and, for KITTI, the longer volume of interest). Bad input stops the import with a
message naming the file and line, and leaves no output file.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from common.datasets import kitti_odometry, kitti_raw, kitti_tracking, middlebury
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
    else:
        frames = middlebury.import_scenes(args.folder, args.out, args.max_frames)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.1f} MB, {frames} frames) "
          f"in {time.perf_counter() - start:.1f} s")
    return 0
