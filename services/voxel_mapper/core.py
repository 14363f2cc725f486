"""Steps 3 and 4 of the paper: the world voxel map updated with egomotion, then colour clustering.

``VoxelMapper.process(cloud, ego)`` reads as the paper: follow the world epoch, update the map with
this frame's points brought into the world (Sect. IV-A), find the road, select the voxels above it
inside the volume of interest, flood-fill them by colour (Alg. IV-B.1, Eq. 1), join the parts of
one object (an addition, see ``linkage``) unless their corners move apart (``apart``), cut low
objects off tall structures they were filled into (an addition, see ``skyline``), aggregate small
clusters (Alg. IV-B.2) that their corners do not keep apart, remove noise (Alg. IV-B.3), cut
groups of people apart (an addition, see ``groups``) and describe what is left.

World-state policy: a new ``world_epoch`` resets the map (its world frame is gone). An invalid
egomotion also restarts the map from this frame alone: its pose is odometry's prediction, good
enough to place this frame's clusters but not to fuse them with voxels seen under another pose.
A voxel without points this frame is removed, as in the paper. Keeping unseen voxels for a short
decay was measured with the final defaults on synthetic urban and slope (seed 1, odometry poses,
stereo clouds; docs/results/voxel.md): ``keep_frames=1`` took objects in one cluster 76 -> 71 %
and 73 -> 69 %, merged clusters 6 -> 13 % and 11 -> 19 %, phantom clusters on urban 0.05 -> 0.17
per frame (moving objects' trails join what they pass, stereo streaks persist); ``keep_frames=2``
was worse again (60 % and 56 % in one cluster). The paper's rule is kept: what is reported is
what was seen this frame.

The sequential kernels (map insert, flood fill, links) are numba-compiled with ``cache=True``:
a flood fill with a running mean cannot be vectorised, pure Python took ~240 ms for 6,700 voxels,
and the compiled map update is one hash insert per point (~30 ns) where numpy would sort the keys.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.config import Config, VolumeConfig
from common.errors import ConfigError, InputError
from common.geometry import transform
from common.messages import Cluster, Clusters, EgoMotion, PointCloud
from services.voxel_mapper.apart import NEVER_APART, Apart, ApartRule, PartMotion
from services.voxel_mapper.flood_fill import flood_fill, touching_pairs
from services.voxel_mapper.groups import split_groups
from services.voxel_mapper.join_model import JoinModel
from services.voxel_mapper.linkage import Learned, join_parts
from services.voxel_mapper.refinement import aggregate, remove_noise
from services.voxel_mapper.skyline import cut_low_parts
from services.voxel_mapper.summary import describe
from services.voxel_mapper.terrain import FlatGround, TerrainProfile
from services.voxel_mapper.voxel_map import VoxelMap

Ground = FlatGround | TerrainProfile

#: points nearer than this (m, along the vehicle's x from where they were seen) give no bearing.
VIEW_MIN_X: float = 1.0


def view_limits(cloud: PointCloud) -> npt.NDArray[np.float64]:
    """Where the cloud was seen from (x, y) and the slopes of its leftmost and rightmost bearings.

    Every point is a pixel reprojected, so no bearing lies outside the image: the extremes are the
    side edges of what the matcher gave depth to, narrower than the lens's by the band of columns
    it leaves without disparity. Without points ahead the view is unknown (both slopes 0).
    """
    origin = np.asarray(cloud.origin, dtype=np.float64)
    unknown = np.array([origin[0], origin[1], 0.0, 0.0])
    # float32 as sent, one column at a time: a float64 copy of 200k points took 10 ms, this 0.5
    points = np.asarray(cloud.points)
    x, y = points[:, 0] - np.float32(origin[0]), points[:, 1] - np.float32(origin[1])
    ahead = x > VIEW_MIN_X  # a NaN is not ahead
    slope = y[ahead] / x[ahead]
    if slope.size and not np.isfinite(slope.max() - slope.min()):  # NaN or inf: never from the bus, which refuses them
        slope = slope[np.isfinite(slope)]
    if slope.size == 0:
        return unknown
    return np.array([origin[0], origin[1], slope.max(), slope.min()])


@dataclass(frozen=True)
class PartsSeen:
    """The flood fill's parts of one frame, before any are joined: what scripts/train_join_model.py learns from."""

    vmap: VoxelMap
    labels: npt.NDArray[np.int32]
    n_parts: int
    position: npt.NDArray[np.float64]  # the camera's (world)
    height: npt.NDArray[np.float64]  # each map slot's above the road
    min_voxels: int  # parts smaller than this are never joined (voxel.join_min_voxels)
    bridge_voxels: int
    step_voxels: int


class VoxelMapper:
    """Pure core of the voxel_mapper service: PointCloud + EgoMotion -> Clusters."""

    def __init__(self, *, edge: float, volume: VolumeConfig, ground: Ground, epsilon: float,
                 min_cluster_voxels: int, min_density: float, min_points_per_voxel: int = 1,
                 keep_frames: int = 0, ground_clearance: float = 0.2, join_share: float = 0.3,
                 bridge_voxels: int = 3, points_range_m: float = 0.0, min_points_far: int = 2,
                 join_min_voxels: int = 0, cut_tall_m: float = 0.0, cut_low_m: float = 2.2,
                 cut_min_voxels: int = 12, step_voxels: int = 0, group_dense_share: float = 0.0,
                 group_min_voxels: int = 40, aggregate_in_turn_m: float = 0.0, circular_hue: bool = False,
                 apart: ApartRule = NEVER_APART, join_model: JoinModel | None = None,
                 join_probability: float = 0.8, join_veto: float = 0.5) -> None:
        if edge <= 0.0:
            raise ConfigError(f"voxel.edge must be > 0, got {edge}")
        self.map = VoxelMap(edge, keep_frames, circular_hue=circular_hue)
        self.volume = volume
        self.seen = volume.seen()  # mapped and clustered: the volume and its lookahead beyond
        self.ground = ground
        self.epsilon = epsilon
        self.min_cluster_voxels = min_cluster_voxels
        self.min_density = min_density
        self.aggregate_in_turn_m = aggregate_in_turn_m
        self.min_points = min_points_per_voxel
        self.clearance = ground_clearance
        self.join_share = join_share
        self.bridge_voxels = bridge_voxels
        self.step_voxels = step_voxels
        self.points_range = points_range_m
        self.min_points_far = min_points_far
        self.join_min = join_min_voxels if join_min_voxels > 0 else min_cluster_voxels
        self.join_model = join_model
        self.join_probability = join_probability
        self.join_veto = join_veto
        self.parts_seen: Callable[[PartsSeen], None] | None = None  # shown the flood fill's parts (training)
        self.cut = (cut_tall_m, cut_low_m, cut_min_voxels)
        self.groups = (group_dense_share, group_min_voxels)
        self.epoch: int | None = None
        self.parts = PartMotion(apart)
        self._corner_ids = np.zeros(0, dtype=np.int64)  # the corners passed on last frame

    @classmethod
    def from_config(cls, cfg: Config) -> VoxelMapper:
        v, vol = cfg.voxel, cfg.volume
        seen = vol.seen()
        if v.ground == "flat":
            ground: Ground = FlatGround()
        elif v.ground == "terrain":
            ground = TerrainProfile(x_min=seen.x_min, x_max=seen.x_max, z_min=seen.z_min - 1.0, z_max=seen.z_max,
                                    slice_m=v.terrain_slice, max_grade=v.terrain_max_grade)
        else:
            raise ConfigError(f"voxel.ground must be 'flat' or 'terrain', got {v.ground!r}")
        return cls(edge=v.edge, volume=vol, ground=ground, epsilon=v.epsilon,
                   min_cluster_voxels=v.min_cluster_voxels, min_density=v.min_density,
                   min_points_per_voxel=v.min_points_per_voxel, keep_frames=v.keep_frames,
                   ground_clearance=v.ground_clearance, join_share=v.join_share, bridge_voxels=v.bridge_voxels,
                   points_range_m=v.points_range_m, min_points_far=v.min_points_far,
                   join_min_voxels=v.join_min_voxels, cut_tall_m=v.cut_tall_m, cut_low_m=v.cut_low_m,
                   cut_min_voxels=v.cut_min_voxels, step_voxels=v.step_bridge_voxels,
                   group_dense_share=v.group_dense_share, group_min_voxels=v.group_min_voxels,
                   aggregate_in_turn_m=v.aggregate_in_turn_m, circular_hue=v.circular_hue,
                   apart=ApartRule(v.apart_min_corners, v.apart_across_mps, v.apart_sigma_k, v.apart_still_mps,
                                   v.apart_samples, cfg.tracker.corner_across_std_m),
                   join_model=JoinModel.configured(v.join_model), join_probability=v.join_probability,
                   join_veto=v.join_veto)

    def process(self, cloud: PointCloud, ego: EgoMotion) -> Clusters:
        """Update the map with one frame and cluster the voxels above the road."""
        points, colors = self._checked(cloud)
        self._follow_epoch(ego)
        self.map.integrate(points, colors, ego.pose)
        self.map.forget_unseen()
        road = self.ground.fit(points)
        candidate, height = self._above_road(road, ego.pose)
        labels, n_clusters = flood_fill(self.map, candidate, self.epsilon)
        corners = transform(ego.pose, np.asarray(cloud.keypoints, dtype=np.float64))
        corner_slots = self.map.slots_at(corners)  # the map's voxels stay as they are from here on
        apart = self._apart(cloud, corners, corner_slots, candidate, labels, n_clusters, ego)
        if self.parts_seen is not None:
            self.parts_seen(PartsSeen(self.map, labels, n_clusters, ego.pose[:3, 3], height, self.join_min,
                                      self.bridge_voxels, self.step_voxels))
        learned = None if self.join_model is None else Learned(self.join_model, self.join_probability, height,
                                                                   self.join_veto)
        labels = join_parts(self.map, labels, n_clusters, ego.pose[:3, 3], self.join_min,
                            self.join_share, self.bridge_voxels, self.step_voxels, apart, learned)
        if self.cut[0] > 0.0:
            labels, n_clusters = cut_low_parts(labels, n_clusters, self.map.coords, height, *self.cut)
        pairs = touching_pairs(self.map, labels)
        if apart is not None and len(pairs):  # judged again: the joined parts' corners together
            joined = self.parts.judge(self.map.coords, labels, n_clusters, ego.pose[:3, 3], self.map.edge)
            pairs = pairs[~joined(pairs[:, 0], pairs[:, 1])]
        labels = aggregate(labels, n_clusters, pairs, self.min_cluster_voxels, self._near(labels, n_clusters, ego.pose))
        labels = remove_noise(labels, self.map.coords, n_clusters, self.min_cluster_voxels, self.min_density)
        labels, n_clusters = split_groups(labels, n_clusters, self.map.coords, self.map.hits, *self.groups,
                                          self.map.edge)
        on = self._corners_on_clusters(np.asarray(cloud.keypoint_ids), corner_slots, labels)
        inside, beyond = self._split_beyond(describe(self.map, labels, height), ego.pose)
        return Clusters(frame_id=cloud.frame_id, stamp_ns=cloud.stamp_ns, clusters=inside,
                        voxel_edge=self.map.edge, world_epoch=ego.world_epoch, ego_pose=np.array(ego.pose),
                        voxel_count=self.map.n, view=view_limits(cloud), keypoint_ids=cloud.keypoint_ids[on],
                        keypoints=corners[on], keypoint_std=cloud.keypoint_std[on], beyond=beyond)

    def _split_beyond(self, clusters: list[Cluster], pose: npt.NDArray[np.float64]
                      ) -> tuple[list[Cluster], list[Cluster]]:
        """The clusters centred in the volume, and those centred beyond its far end (in the lookahead)."""
        if self.seen.x_max <= self.volume.x_max or not clusters:
            return clusters, []
        ahead = (np.array([c.centroid for c in clusters]) - pose[:3, 3]) @ pose[:3, 0]  # vehicle x
        far = ahead > self.volume.x_max
        return ([c for c, f in zip(clusters, far, strict=True) if not f],
                [c for c, f in zip(clusters, far, strict=True) if f])

    def _apart(self, cloud: PointCloud, corners: npt.NDArray[np.float64], slots: npt.NDArray[np.int64],
               candidate: npt.NDArray[np.bool_], labels: npt.NDArray[np.int32], n_parts: int, ego: EgoMotion
               ) -> Apart | None:
        """The flood fill's parts that their corners keep apart (apart.py); None when that is off."""
        if not self.parts.on:
            return None
        above_road = slots >= 0
        above_road[above_road] = candidate[slots[above_road]]
        self.parts.follow(np.asarray(cloud.keypoint_ids), corners, np.asarray(cloud.keypoint_std), above_road,
                          cloud.stamp_ns, ego.world_epoch)
        return self.parts.judge(self.map.coords, labels, n_parts, ego.pose[:3, 3], self.map.edge)

    def _corners_on_clusters(self, ids: npt.NDArray[np.int64], slots: npt.NDArray[np.int64],
                             labels: npt.NDArray[np.int32]) -> npt.NDArray[np.bool_]:
        """Which followed corners to pass on (``slots``: the map's voxel each lies in, -1: none): those
        in a cluster's voxel this frame, and those passed on last frame, so that a corner is passed on
        from the frame it first lies on a cluster for as long as the stereo stage follows it.

        Only such a corner is of use to the tracker, which reads the ones in its clusters' voxels and
        their history. Of the stereo stage's 2,200-2,700 corners a frame on synthetic urban and
        crossing, three quarters to six sevenths lie on the road or on nothing clustered, and they
        made most of the Clusters message (urban-s7: 114 -> 47 kB a frame, median). A corner's own
        disparity can place it a voxel off its surface for a frame; passed on only while in a
        cluster's voxel, its history broke, and held out 10 fewer moving frames were found
        (docs/results/tracking.md, "Session 41").
        """
        on = slots >= 0
        on[on] = labels[slots[on]] >= 0
        on |= np.isin(ids, self._corner_ids)
        self._corner_ids = ids[on]
        return on

    def _near(self, labels: npt.NDArray[np.int32], n_clusters: int, pose: npt.NDArray[np.float64]
              ) -> npt.NDArray[np.bool_] | None:
        """Clusters whose mean voxel lies within ``aggregate_in_turn_m`` of the vehicle (x, y); None when off."""
        if self.aggregate_in_turn_m <= 0.0:
            return None
        inside = labels >= 0
        lab, offset = labels[inside], self.map.centroids[inside, 0:2] - pose[0:2, 3]
        count = np.maximum(np.bincount(lab, minlength=n_clusters), 1)
        mean_x = np.bincount(lab, offset[:, 0], minlength=n_clusters) / count
        mean_y = np.bincount(lab, offset[:, 1], minlength=n_clusters) / count
        return np.hypot(mean_x, mean_y) < self.aggregate_in_turn_m

    @staticmethod
    def _checked(cloud: PointCloud) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
        points, colors = np.asarray(cloud.points), np.asarray(cloud.colors)
        if points.ndim != 2 or points.shape[1] != 3 or colors.shape != points.shape:
            raise InputError(f"point cloud {cloud.frame_id}: points {points.shape} and colours {colors.shape} "
                             "must both be Nx3")
        return points, colors

    def _follow_epoch(self, ego: EgoMotion) -> None:
        if ego.world_epoch != self.epoch or not ego.valid:
            self.map.clear()
        self.epoch = ego.world_epoch

    def _min_points(self, local: npt.NDArray[np.float64]) -> npt.NDArray[np.float64] | int:
        """Points a voxel needs: fewer beyond ``points_range`` as a pixel's footprint grows with range squared."""
        if self.points_range <= 0.0:
            return self.min_points
        scale = np.minimum(1.0, (self.points_range / np.maximum(np.hypot(local[:, 0], local[:, 1]), 1e-3)) ** 2)
        return np.maximum(self.min_points_far, self.min_points * scale)

    def _above_road(self, road: Ground, pose: npt.NDArray[np.float64]
                    ) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.float64]]:
        """Voxels inside the volume of interest and above the road (judged in this vehicle frame), and every
        voxel's height above the road."""
        vol = self.seen
        offset = self.map.centroids - pose[:3, 3]
        rot = pose[:3, :3]  # world -> vehicle frame is offset @ rot, written out to stay off BLAS threads
        local = offset[:, 0:1] * rot[0] + offset[:, 1:2] * rot[1] + offset[:, 2:3] * rot[2]
        height = road.height(local)
        inside = ((self.map.counts >= self._min_points(local)) & (height > self.clearance) & (height <= vol.z_max)
                  & (local[:, 0] >= vol.x_min) & (local[:, 0] <= vol.x_max) & (np.abs(local[:, 1]) <= vol.y_half))
        return inside, height
