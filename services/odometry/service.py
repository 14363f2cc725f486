"""odometry on the bus: ``camera/stereo`` -> ``odometry/ego``.

World epoch on start: the wall clock in milliseconds. A restarted odometry must re-anchor with
an epoch larger than any it published before (the voxel mapper and tracker reset their world on
a new epoch and ignore older ones). The core adds one per re-anchor, at most once per frame, and
frames are more than a millisecond apart, so a process started later always starts higher —
without having to hear the previous instance's last message, which may never have been sent.

Empty output for a frame the core fails on: ``valid=False``, the last published pose held,
identity motion, no inliers, the current epoch — "motion unknown", which downstream treats as
an untrusted frame rather than a jump to the world origin.
"""

from __future__ import annotations

import time

import numpy as np

from common.config import Config
from common.messages import EgoMotion, StereoFrame
from services.odometry import StereoOdometry
from services.shell import Stage

NAME = "odometry"


def start_epoch() -> int:
    """A world epoch larger than any a previous instance can have reached: wall-clock ms."""
    return time.time_ns() // 1_000_000


def stage(cfg: Config, initial_epoch: int | None = None) -> Stage:
    epoch = start_epoch() if initial_epoch is None else initial_epoch
    core = StereoOdometry.from_config(cfg, initial_epoch=epoch)
    last = EgoMotion(frame_id=-1, stamp_ns=0, world_epoch=epoch)

    def process(frame: StereoFrame) -> tuple[EgoMotion]:
        nonlocal last
        last = core.process(frame)
        return (last,)

    def empty(frame: StereoFrame) -> tuple[EgoMotion]:
        held = EgoMotion(
            frame_id=frame.frame_id,
            stamp_ns=frame.stamp_ns,
            pose=np.array(last.pose),
            valid=False,
            world_epoch=max(last.world_epoch, getattr(core, "epoch", epoch)),
        )
        return (held,)

    return Stage(
        name=NAME,
        inputs={"camera/stereo": StereoFrame},
        outputs=("odometry/ego",),
        process=process,
        empty=empty,
        degenerate=lambda: not last.valid,
    )

