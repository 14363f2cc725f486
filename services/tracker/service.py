"""tracker on the bus: ``voxel_mapper/clusters`` + ``odometry/ego`` (joined by frame id) -> ``tracker/obstacles``.

The Obstacles of frame k are the pipeline's last word on that frame: a lockstep replay waits for
them before it sends frame k + 1. Empty output for a frame the core fails on: no obstacles, with
the frame's ego pose and epoch, so that wait always ends.
"""

from __future__ import annotations

import numpy as np

from common.config import Config
from common.messages import Clusters, EgoMotion, Obstacles
from services.shell import Stage
from services.tracker import Tracker

NAME = "tracker"


def empty(clusters: Clusters, ego: EgoMotion) -> tuple[Obstacles]:
    return (
        Obstacles(
            frame_id=clusters.frame_id,
            stamp_ns=clusters.stamp_ns,
            world_epoch=ego.world_epoch,
            ego_pose=np.array(ego.pose),
        ),
    )


def stage(cfg: Config) -> Stage:
    core = Tracker.from_config(cfg)

    def process(clusters: Clusters, ego: EgoMotion) -> tuple[Obstacles]:
        return (core.process(clusters, ego),)

    return Stage(
        name=NAME,
        inputs={"voxel_mapper/clusters": Clusters, "odometry/ego": EgoMotion},
        outputs=("tracker/obstacles",),
        process=process,
        empty=empty,
        counters=lambda: dict(getattr(core, "counters", {})),
    )
