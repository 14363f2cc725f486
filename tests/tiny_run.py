"""A run recording written by hand: flat images and tracks whose place in the picture is known.

Two tracked obstacles (one moving, one stationary) stand still in the world while the vehicle
drives forward and turns a little, so every frame tests the whole world -> vehicle -> camera
chain with a different ego pose.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from common import messages as sv
from common.geometry import make_pose, rot_z
from common.recording import RecordingWriter

WIDTH, HEIGHT = 320, 240
CALIB = sv.Calibration(
    fx=300.0, fy=300.0, cx=160.0, cy=120.0, baseline=0.4, width=WIDTH, height=HEIGHT,
    cam_to_vehicle=np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 1.5], [0.0, 0.0, 0.0, 1.0]]),
)
GREY = 128
START_NS = 1_700_000_000_000_000_000
PERIOD_NS = 100_000_000
VOXEL_EDGE = 0.25


def ego_pose(i: int) -> np.ndarray:
    """Vehicle pose in the world at frame ``i``: 1 m forward and 0.02 rad left per frame."""
    return make_pose(rot_z(0.02 * i), [1.0 * i, 0.1 * i, 0.0])


def obstacle(ident: int, lo: list[float], hi: list[float], velocity: list[float], moving: bool) -> sv.Obstacle:
    lo_a, hi_a = np.array(lo), np.array(hi)
    vel = np.array(velocity, dtype=np.float64)
    return sv.Obstacle(
        id=ident, state="tracked", centroid=(lo_a + hi_a) / 2, bbox_min=lo_a, bbox_max=hi_a,
        volume=float(np.prod(hi_a - lo_a)), velocity=vel, velocity_rel=vel, speed=float(np.linalg.norm(vel)),
        moving=moving, position_cov=np.eye(3) * 0.1, velocity_cov=np.eye(3) * 0.1, age=5,
        color_rgb=np.array([0.5, 0.5, 0.5], dtype=np.float32),
    )


#: the moving obstacle (left of the road, driving away) and the stationary one (right).
MOVING = obstacle(7, [14.0, 1.5, 0.0], [18.0, 3.5, 1.6], [3.0, 0.0, 0.0], True)
STATIONARY = obstacle(9, [16.0, -4.5, 0.0], [17.0, -2.5, 2.0], [0.0, 0.0, 0.0], False)


def cluster(ob: sv.Obstacle) -> sv.Cluster:
    lo = np.floor(ob.bbox_min / VOXEL_EDGE).astype(np.int32)
    voxels = lo + np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.int32)
    zeros = np.zeros(3, dtype=np.float32)
    return sv.Cluster(
        id=ob.id, voxels=voxels, voxel_count=3, color_mean_rgb=np.array([0.8, 0.2, 0.2], dtype=np.float32),
        color_var_rgb=zeros, color_mean_hsl=zeros, color_var_hsl=zeros, bbox_min=ob.bbox_min, bbox_max=ob.bbox_max,
        centroid=ob.centroid, density=0.5, volume=3 * VOXEL_EDGE**3,
    )


def write_run(path: Path, frames: int = 3, extra_truth: tuple[sv.GroundTruthObject, ...] = ()) -> Path:
    """A run recording as ``process`` writes one: camera, points, ego, clusters, tracks, truth.

    The truth is one car where the moving track is, plus ``extra_truth``.
    """
    image = np.full((HEIGHT, WIDTH, 3), GREY, dtype=np.uint8)
    rng = np.random.default_rng(0)
    disparity = np.tile(np.linspace(1.0, 40.0, WIDTH, dtype=np.float32), (HEIGHT, 1))
    disparity[:10] = np.nan  # invalid rows, as the matcher leaves them
    with RecordingWriter(path) as writer:
        writer.describe(None, {"source": "synthetic", "frames": frames, "frame_rate_hz": 10.0})
        for i in range(frames):
            stamp = START_NS + i * PERIOD_NS
            pose = ego_pose(i)
            points = rng.uniform(-5, 20, (50, 3)).astype(np.float32)
            colours = rng.integers(0, 256, (50, 3), dtype=np.uint8)
            truth = sv.GroundTruthObject(id=1, cls="car", center=MOVING.centroid, size=np.array([4.0, 2.0, 1.6]),
                                         yaw=0.0, velocity=MOVING.velocity, moving=True)
            for topic, msg in (
                ("camera/stereo", sv.StereoFrame(frame_id=i, stamp_ns=stamp, left=image, right=image, calib=CALIB,
                                                 image_format="png")),
                ("stereo_depth/points", sv.PointCloud(frame_id=i, stamp_ns=stamp, points=points, colors=colours)),
                ("stereo_depth/disparity", sv.Disparity(frame_id=i, stamp_ns=stamp, disparity=disparity, calib=CALIB)),
                ("odometry/ego", sv.EgoMotion(frame_id=i, stamp_ns=stamp, pose=pose, valid=True)),
                ("voxel_mapper/clusters", sv.Clusters(frame_id=i, stamp_ns=stamp, voxel_edge=VOXEL_EDGE, ego_pose=pose,
                                                      clusters=[cluster(MOVING), cluster(STATIONARY)])),
                ("tracker/obstacles", sv.Obstacles(frame_id=i, stamp_ns=stamp, obstacles=[MOVING, STATIONARY],
                                                   ego_pose=pose)),
                ("groundtruth/objects", sv.GroundTruthObjects(frame_id=i, stamp_ns=stamp,
                                                              objects=[truth, *extra_truth])),
            ):
                writer.write(sv.key_for(topic), msg)
    return path
