"""stereo_depth on the bus: ``camera/stereo`` -> ``stereo_depth/points`` + ``stereo_depth/disparity``.

Empty output for a frame the core fails on: a cloud without points and an all-NaN disparity of
the frame's size (with its calibration), so evaluation counts every pixel of it as missing
instead of waiting for a frame that never comes.
"""

from __future__ import annotations

import numpy as np

from common.config import Config
from common.messages import Disparity, Message, PointCloud, StereoFrame
from services import warmup
from services.shell import Stage
from services.stereo_depth import StereoDepth

NAME = "stereo_depth"


def empty(frame: StereoFrame) -> tuple[PointCloud, Disparity]:
    height, width = frame.left.shape[:2]
    cloud = PointCloud(
        frame_id=frame.frame_id,
        stamp_ns=frame.stamp_ns,
        points=np.zeros((0, 3), np.float32),
        colors=np.zeros((0, 3), np.uint8),
    )
    disparity = Disparity(
        frame_id=frame.frame_id,
        stamp_ns=frame.stamp_ns,
        disparity=np.full((height, width), np.nan, np.float32),
        calib=frame.calib,
    )
    return cloud, disparity


def stage(cfg: Config) -> Stage:
    core = StereoDepth.from_config(cfg)

    def process(frame: StereoFrame) -> tuple[Message, ...]:
        return tuple(core.process(frame))

    return Stage(
        name=NAME,
        inputs={"camera/stereo": StereoFrame},
        outputs=("stereo_depth/points", "stereo_depth/disparity"),
        process=process,
        empty=empty,
        degenerate=lambda: core.last_degenerate,
        warm=lambda: warmup.warm(NAME, lambda: StereoDepth.from_config(cfg).process, warmup.stereo_inputs),
    )
