"""Writing an imported dataset: one recording, frame by frame, in the layout the simulator uses.

Each importer yields, per frame, the messages that frame contributes (a StereoFrame and whatever
ground truth the dataset has); this module files them under their keys, atomically, so a bad
file found halfway through leaves no recording that looks complete.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from common.config import Config, VolumeConfig
from common.datasets.kitti_calib import calibration_info
from common.messages import TOPICS, Calibration, Message, key_for
from common.progress import progress
from common.recording import RecordingWriter

#: KITTI's longer baseline and focal length see farther (EVALUATION.md).
KITTI_VOLUME = VolumeConfig(x_min=0.0, x_max=45.0, y_half=10.0, z_min=0.0, z_max=3.5)
FRAME_RATE_HZ: float = 10.0
#: KITTI's disparities against its Velodyne (2011_09_26 rig, raw 0009 frames 0/25/50; OpenCV's SGBM
#: shows the same): 0.16 px too small, more towards the image sides, which makes every depth and so
#: the odometry's scale ~2.7 % too long. Odometry and the points correct for it; docs/results/odometry.md.
KITTI_BIAS: dict[str, float] = {"disparity_offset_px": 0.16, "disparity_edge_px": 1.3}
KITTI_SETTINGS: dict[str, dict[str, float]] = {"odometry": KITTI_BIAS, "stereo": KITTI_BIAS}
#: topic of each message type (every type has one topic).
TOPIC_OF: dict[type[Message], str] = {cls: topic for topic, cls in TOPICS.items()}


def recording_info(source: str, scenario: str, frames: int, calib: Calibration,
                   volume: VolumeConfig | None = KITTI_VOLUME,
                   settings: dict[str, dict[str, float]] | None = KITTI_SETTINGS, **extra: Any) -> dict[str, Any]:
    """The info metadata every importer stores (PREAMBLE's convention); real data is never complete.

    ``settings`` are configuration values that belong to the sensor rig rather than to a run;
    ``process`` and ``demo`` apply them (under a user's ``--config`` and ``--set``).
    """
    info: dict[str, Any] = {"source": source, "scenario": scenario, "gt_complete": False,
                            "frame_rate_hz": FRAME_RATE_HZ, "frames": frames, "calib": calibration_info(calib)}
    if volume is not None:
        info["volume"] = dataclasses.asdict(volume)
    if settings:
        info["settings"] = settings
    return {**info, **extra}


def write_frames(out: Path, info: dict[str, Any], frames: Iterable[list[Message]], description: str) -> int:
    """Write every frame's messages under their keys; returns the number of frames written."""
    written = 0
    with RecordingWriter(out, atomic=True) as writer:
        writer.describe(Config().to_dict(), info)  # the defaults a `process` of this file starts from
        for messages in progress(frames, int(info["frames"]), description):
            for msg in messages:
                writer.write(key_for(TOPIC_OF[type(msg)]), msg, log_time_ns=msg.stamp_ns)
            written += 1
    return written
