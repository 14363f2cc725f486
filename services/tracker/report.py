"""Tracks as the Obstacles message: one obstacle per track of every queue, world frame.

A track's reported centroid is its filtered position plus the offset of the last cluster it took,
so a seen obstacle sits exactly on its cluster and a ghost moves on with the prediction; its box
is that cluster's, carried along. ``velocity_rel`` is the obstacle's world velocity minus the
vehicle's, turned into the vehicle's axes.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from common.messages import Clusters, EgoMotion, Obstacle, Obstacles
from services.tracker.motion_state import speed_and_sigma
from services.tracker.track import QUEUE_NAMES, TrackTable

NDArray = npt.NDArray[Any]


def obstacles_of(t: TrackTable, ego_velocity: NDArray, clusters: Clusters, ego: EgoMotion) -> Obstacles:
    """The message for this frame; arrays are fresh copies, never views of the track store."""
    centroid = t.x[:, 0:3] + t.offset
    shift = centroid - t.centroid
    bbox_min, bbox_max = t.bbox_min + shift, t.bbox_max + shift
    velocity = t.x[:, 3:6].copy()
    speed, _ = speed_and_sigma(velocity, t.p[:, 3:6, 3:6])
    rotation = ego.pose[0:3, 0:3] if np.isfinite(ego.pose).all() else np.eye(3)
    velocity_rel = (velocity - ego_velocity) @ rotation  # R^T (v - v_ego), row-wise
    position_cov = t.p[:, 0:3, 0:3].copy()
    velocity_cov = t.p[:, 3:6, 3:6].copy()
    colour = t.rgb.astype(np.float32)
    scalars = [c.tolist() for c in (t.ids, t.queue, t.volume, speed, t.moving, t.age)]
    # ``list`` splits each array into its row views in one call: indexing row by row costs twice as much
    rows = [list(a) for a in (centroid, bbox_min, bbox_max, velocity, velocity_rel, position_cov, velocity_cov, colour)]
    obstacles = [
        Obstacle(
            id=track_id,
            state=QUEUE_NAMES[queue],
            centroid=c,
            bbox_min=lo,
            bbox_max=hi,
            volume=volume,
            velocity=v,
            velocity_rel=v_rel,
            speed=s,
            moving=moving,
            position_cov=p_cov,
            velocity_cov=v_cov,
            age=age,
            color_rgb=rgb,
        )
        for track_id, queue, volume, s, moving, age, c, lo, hi, v, v_rel, p_cov, v_cov, rgb in zip(
            *scalars, *rows, strict=True
        )
    ]
    return Obstacles(
        frame_id=clusters.frame_id,
        stamp_ns=clusters.stamp_ns,
        obstacles=obstacles,
        world_epoch=clusters.world_epoch,
        ego_pose=np.array(ego.pose, dtype=np.float64),
    )
