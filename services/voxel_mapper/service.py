"""voxel_mapper on the bus: ``stereo_depth/points`` + ``odometry/ego``, joined by frame id -> ``voxel_mapper/clusters``.

Empty output for a frame the core fails on: no clusters and no voxels, with the frame's ego pose
and world epoch, so the tracker still advances one frame (its tracks age, as for a frame in which
nothing was seen) and the lockstep replay gets its obstacles for that frame.
"""

from __future__ import annotations

import numpy as np

from common.config import Config
from common.messages import Clusters, EgoMotion, PointCloud
from services import warmup
from services.shell import Stage
from services.voxel_mapper import VoxelMapper

NAME = "voxel_mapper"


def stage(cfg: Config) -> Stage:
    core = VoxelMapper.from_config(cfg)

    def process(cloud: PointCloud, ego: EgoMotion) -> tuple[Clusters]:
        return (core.process(cloud, ego),)

    def empty(cloud: PointCloud, ego: EgoMotion) -> tuple[Clusters]:
        return (
            Clusters(
                frame_id=cloud.frame_id,
                stamp_ns=cloud.stamp_ns,
                voxel_edge=cfg.voxel.edge,
                world_epoch=ego.world_epoch,
                ego_pose=np.array(ego.pose),
            ),
        )

    return Stage(
        name=NAME,
        inputs={"stereo_depth/points": PointCloud, "odometry/ego": EgoMotion},
        outputs=("voxel_mapper/clusters",),
        process=process,
        empty=empty,
        counters=lambda: dict(getattr(core, "counters", {})),
        warm=lambda: warmup.warm(NAME, lambda: VoxelMapper.from_config(cfg).process, warmup.clouds_and_motions),
    )

