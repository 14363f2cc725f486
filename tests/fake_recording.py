"""Small recordings written directly with RecordingWriter: 64x48 stereo frames and ground truth.

The tests of the recorder and the replay need recordings before the scenario generator exists;
these are deterministic (seeded), tiny, and cover every key replay publishes by default.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from common.config import Config
from common.messages import Calibration, GroundTruthEgo, GroundTruthObject, GroundTruthObjects, StereoFrame, key_for
from common.recording import RecordingWriter

CALIB = Calibration(fx=50.0, fy=50.0, cx=32.0, cy=24.0, baseline=0.5, width=64, height=48)
PERIOD_NS = 100_000_000
START_NS = 1_700_000_000_000_000_000


def frame(i: int, rng: np.random.Generator, fmt: str = "raw") -> StereoFrame:
    left = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    right = np.roll(left, -3, axis=1)
    return StereoFrame(frame_id=i, stamp_ns=START_NS + i * PERIOD_NS, left=left, right=right, calib=CALIB,
                       image_format=fmt)


def ground_truth(i: int) -> tuple[GroundTruthEgo, GroundTruthObjects]:
    stamp = START_NS + i * PERIOD_NS
    pose = np.eye(4)
    pose[0, 3] = 0.5 * i
    obj = GroundTruthObject(id=1, cls="car", center=np.array([10.0 - 0.2 * i, 1.0, 0.8]),
                            size=np.array([4.0, 1.8, 1.5]), yaw=0.1, velocity=np.array([-2.0, 0.0, 0.0]), moving=True)
    return (GroundTruthEgo(frame_id=i, stamp_ns=stamp, pose=pose, velocity=np.array([5.0, 0.0, 0.0])),
            GroundTruthObjects(frame_id=i, stamp_ns=stamp, objects=[obj], gt_complete=True,
                               dontcare=np.array([[0.0, 0.0, 8.0, 6.0]], dtype=np.float32)))


def write_recording(path: Path, frames: int, chunk_size: int = 1024 * 1024, compression: str = "zstd") -> None:
    """A small self-contained recording: stereo frames and two ground-truth keys per frame."""
    rng = np.random.default_rng(7)
    with RecordingWriter(path, compression=compression, chunk_size=chunk_size) as w:
        w.describe(Config().to_dict(), {"source": "synthetic", "frames": frames, "frame_rate_hz": 10.0})
        for i in range(frames):
            ego, objects = ground_truth(i)
            w.write(key_for("camera/stereo"), frame(i, rng), log_time_ns=START_NS + i * PERIOD_NS)
            w.write(key_for("groundtruth/ego"), ego, log_time_ns=START_NS + i * PERIOD_NS)
            w.write(key_for("groundtruth/objects"), objects, log_time_ns=START_NS + i * PERIOD_NS)
