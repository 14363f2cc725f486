"""odometry on the bus: ``camera/stereo`` (and ``vehicle/motion`` when fusing) -> ``odometry/ego``.

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
from common.messages import EgoMotion, Message, StereoFrame, VehicleMotion
from services import warmup
from services.odometry import StereoOdometry
from services.shell import Stage

NAME = "odometry"


def start_epoch() -> int:
    """A world epoch larger than any a previous instance can have reached: wall-clock ms."""
    return time.time_ns() // 1_000_000


def inputs(cfg: Config) -> dict[str, type[Message]]:
    """The camera, and with ``odometry.fuse_ins`` the vehicle's motion sensors, joined per frame.

    The sensors are an optional input: a frame whose sample has not come goes on with vision alone.
    """
    if cfg.odometry.fuse_ins:
        return {"camera/stereo": StereoFrame, "vehicle/motion": VehicleMotion}
    return {"camera/stereo": StereoFrame}


def stage(cfg: Config, initial_epoch: int | None = None) -> Stage:
    epoch = start_epoch() if initial_epoch is None else initial_epoch
    core = StereoOdometry.from_config(cfg, initial_epoch=epoch)
    last = EgoMotion(frame_id=-1, stamp_ns=0, world_epoch=epoch)

    def process(frame: StereoFrame, vehicle: VehicleMotion | None = None) -> tuple[EgoMotion]:
        nonlocal last
        last = core.process(frame, vehicle)
        return (last,)

    def empty(frame: StereoFrame, *_: Message) -> tuple[EgoMotion]:
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
        inputs=inputs(cfg),
        optional=("vehicle/motion",) if cfg.odometry.fuse_ins else (),
        outputs=("odometry/ego",),
        process=process,
        empty=empty,
        degenerate=lambda: not last.valid,
        warm=lambda: warmup.warm(NAME, lambda: StereoOdometry.from_config(cfg).process, warmup.stereo_inputs),
    )

