"""tracker on the bus: ``voxel_mapper/clusters`` + ``odometry/ego`` (joined by frame id) -> ``tracker/obstacles``.

The Obstacles of frame k are the pipeline's last word on that frame: a lockstep replay waits for
them before it sends frame k + 1. Empty output for a frame the core fails on: no obstacles, with
the frame's ego pose and epoch, so that wait always ends.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from common.config import Config
from common.messages import Clusters, EgoMotion, Obstacles
from services import warmup
from services.shell import Stage
from services.tracker import Tracker
from services.tracker.benchmark import scene

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
        warm=lambda: warmup.warm(NAME, lambda: Tracker.from_config(cfg).process, warm_frames),
    )


def warm_frames() -> list[tuple[Clusters, EgoMotion]]:
    """The tracker benchmark's scene, eight objects and their corners, as off the bus; the first frame
    has every other corner only, so that the second's others take rows between them, as a stereo
    stage's do when it passes a corner on late (common/corner_motion.py, ``_spread``)."""
    frames = scene(warmup.FRAMES, 8, seed=0)
    first, ego = frames[0]
    every_other = slice(None, None, 2)
    frames[0] = (dataclasses.replace(first, keypoint_ids=first.keypoint_ids[every_other],
                                     keypoints=first.keypoints[every_other],
                                     keypoint_std=first.keypoint_std[every_other]), ego)  # fmt: skip
    left = dataclasses.replace(first.clusters[0], id=len(first.clusters))  # where the first object was
    for k in range(3, len(frames)):  # ... still there three frames on: the left-behind test looks
        clusters, ego = frames[k]
        frames[k] = (dataclasses.replace(clusters, clusters=[*clusters.clusters, left]), ego)
    return [(warmup.off_the_wire(c), warmup.off_the_wire(e)) for c, e in frames]
