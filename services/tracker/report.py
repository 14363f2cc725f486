"""Tracks as the Obstacles message: one obstacle per track of every queue, world frame.

A track's reported centroid is its filtered position plus the offset of the last cluster it took,
so a seen obstacle sits exactly on its cluster and a ghost moves on with the prediction; its box
is that cluster's, carried along. ``velocity_rel`` is the obstacle's world velocity minus the
vehicle's, turned into the vehicle's axes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from common.messages import Clusters, EgoMotion, Obstacle, Obstacles
from services.tracker.keypoint_motion import NO_CORNERS, CornerRule, blend_corners
from services.tracker.motion_state import speed_and_sigma
from services.tracker.motion_window import line_velocity
from services.tracker.track import QUEUE_NAMES, TrackTable

NDArray = npt.NDArray[Any]


@dataclass(frozen=True)
class FaceVelocity:
    """The reported velocity, blended with the line through the track's last faces where that is held.

    The filter starts a track at rest and believes its prior for frames: an oncoming car at 9.6 m/s
    was reported at 6.3-7.7 m/s in its first labelled frames, the largest share of urban's speed
    error. The line through its last ``min_faces`` or more faces (0.5 s at 10 Hz) has no prior. Each
    horizontal estimate is weighed by the inverse of its variance; the two share measurements, so the
    blend is a compromise rather than a fusion, and the reported covariance shrinks by the same factor.
    Only a track labelled moving: a standing one's filter weighs each face by what cuts or slides it
    (measurement.py), which the line cannot, and read a block cut by the image's edge 0.5 m/s fast
    where the filter alone says 0.3. The label is not touched (labelling.py decides from the filter
    and the window's bound).
    """

    min_faces: int  # 0: off
    face_std: float  # the faces' scatter is never taken below this (m)

    def blend(self, t: TrackTable, velocity: NDArray, velocity_cov: NDArray) -> None:
        """Blend ``velocity`` (n, 3) and shrink ``velocity_cov`` (n, 3, 3) in place."""
        if self.min_faces <= 0:
            return
        slope, se = line_velocity(t.window, t.window_t, t.window_n, self.min_faces, self.face_std)
        filter_var = np.maximum(0.5 * (velocity_cov[:, 0, 0] + velocity_cov[:, 1, 1]), 1e-12)
        held = np.isfinite(se) & t.moving  # a standing track's filter knows its cuts and slides; the line does not
        if not held.any():
            return
        w = np.where(held, filter_var / (filter_var + np.where(held, se, 1.0) ** 2), 0.0)  # the faces' weight
        velocity[:, 0:2] += w[:, None] * (slope - velocity[:, 0:2])
        velocity_cov[:, 0:2, 0:2] *= (1.0 - w)[:, None, None]


def obstacles_of(
    t: TrackTable,
    ego_velocity: NDArray,
    clusters: Clusters,
    ego: EgoMotion,
    faces: FaceVelocity | None = None,
    corners: CornerRule = NO_CORNERS,
) -> Obstacles:
    """The message for this frame; arrays are fresh copies, never views of the track store."""
    centroid = t.x[:, 0:3] + t.offset
    shift = centroid - t.centroid
    bbox_min, bbox_max = t.bbox_min + shift, t.bbox_max + shift
    velocity = t.x[:, 3:6].copy()
    velocity_cov = t.p[:, 3:6, 3:6].copy()
    if faces is not None and len(t):
        faces.blend(t, velocity, velocity_cov)
    if len(t):
        blend_corners(t, corners, velocity, velocity_cov)
    speed, _ = speed_and_sigma(velocity, velocity_cov)
    rotation = ego.pose[0:3, 0:3] if np.isfinite(ego.pose).all() else np.eye(3)
    velocity_rel = (velocity - ego_velocity) @ rotation  # R^T (v - v_ego), row-wise
    position_cov = t.p[:, 0:3, 0:3].copy()
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
