"""Step 5 of the paper: clusters to tracked obstacles with an absolute velocity.

Each frame: guard the input (stale, new world, gap), predict every track, merge the pieces of
each known object (fragments.py), associate clusters greedily (Algorithm IV-C.1), correct the
associated tracks with a Kalman filter, move tracks between the acceptance, tracked and ghost
queues, start tracks for the clusters left over, and label each track moving or stationary from
its speed (labelling.py). Everything lives in the world frame of the odometry, so a velocity is
over ground; ``velocity_rel`` subtracts the vehicle's own.

The filter follows a cluster's faces turned to the camera (anchor.py), not its centroid, which
slides as more or less of the object comes into view, or its far end where the image's side edge
cuts its near one; the reported centroid is still the cluster's. A measurement further from the
prediction than ``jump_nis`` allows is a cluster that changed shape (split, merged, another face
in view): it re-anchors the position and keeps the velocity, doubted (jumps.py). The velocity
so kept can be stale (learnt from a face that slid, then carried on by re-anchoring: on KITTI
tracking 0001 static structures kept 3-6 m/s for 10-20 frames), so the moving label also needs
the slope of the track's last faces to agree (motion_window.py, labelling.py).
A track whose footprint a few frames back another, standing cluster now holds has slid off what
it followed (hopping along a row of far pieces, each hop within the range noise) and starts
again from rest (left_behind.py).

Bad input is handled where it arrives and counted in ``counters`` (the frame guards are in
clock.py): clusters with non-finite geometry are dropped (``nan_clusters``); a frame whose id is
not newer than the last is ignored and answered with the current tracks unchanged
(``stale_frames``); a gap in frame ids is predicted through with the stamp difference (``gaps``,
``gap_frames``), falling back to the nominal period when stamps do not advance (``bad_stamps``);
a new ``world_epoch`` restarts every track (``epoch_resets``). When the egomotion is flagged
invalid (``ego_invalid``) the clusters were placed in the world with a pose the odometry does not
vouch for: tracks are predicted and still associated (so they stay alive and keep their
identity), but the filter is not corrected and the moving labels are held until a valid frame.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import numpy.typing as npt

from common.config import Config, VolumeConfig
from common.corner_motion import CornerHistory
from common.messages import Cluster, Clusters, EgoMotion, Obstacles
from services.tracker import kalman, motion_window
from services.tracker.anchor import Footprint
from services.tracker.association import Weights, distance_matrix, greedy_pairs, position_variance
from services.tracker.clock import FrameClock
from services.tracker.faces import turn_ends, turn_sides
from services.tracker.fragments import APART_BY_BOX, Sight, Standing, gather, inside_known
from services.tracker.jumps import Jumps
from services.tracker.keypoint_motion import (
    NO_CORNERS,
    CornerRule,
    corner_rule,
    correct_by_corners,
    restart_revived,
    track_corners,
)
from services.tracker.labelling import MotionLabeller
from services.tracker.left_behind import LeftBehind, restart_from_rest
from services.tracker.measurement import cut_covariance, stereo_covariance, view_cut_covariance, visibility_covariance
from services.tracker.motion_model import LearnedLabel, learned_label
from services.tracker.motion_state import EgoVelocity, Hysteresis
from services.tracker.observations import Observations, observe
from services.tracker.parting import NO_PARTING, Parting, cut_by_view, part_covariance, part_tracked
from services.tracker.queues import NO_COASTING, Coasting, advance, coasts
from services.tracker.report import FaceVelocity, obstacles_of
from services.tracker.track import ACCEPTANCE, TRACKED, TrackTable, born, follow_appearance
from services.tracker.twins import NO_TWINS, Twins, wider_twins

NDArray = npt.NDArray[Any]

COUNTERS: tuple[str, ...] = (
    "frames",
    "empty_frames",
    "nan_clusters",
    "stale_frames",
    "gaps",
    "gap_frames",
    "bad_stamps",
    "ego_invalid",
    "epoch_resets",
    "tracks_born",
    "tracks_dropped",
    "slid",
    "parted",
    "corner_restarts",
    "retaken",
)


class Tracker:
    """Greedy association, three queues and a 6-D Kalman filter per track (Sect. IV-C)."""

    def __init__(
        self,
        weights: Weights,
        accept_frames: int,
        ghost_frames: int,
        hysteresis: Hysteresis,
        accel_std: tuple[float, float, float],
        measurement_std: float,
        range_noise_per_m2: float,
        initial_velocity_std: tuple[float, float, float],
        volume: VolumeConfig,
        noise_adaptation: float,
        appearance_smoothing: float,
        frame_period_s: float,
        jump_nis: float = float("inf"),
        fragment_margin: float = -1.0,
        fragment_gap: float = -1.0,
        standing: Standing = APART_BY_BOX,
        accept_misses: int = 0,
        reshape_m: float = float("inf"),
        narrow_across_m: float = 0.0,
        revive_restart_m: float = 0.0,
        merge_growth_m: float = 0.0,
        upright_speed_std: float | None = None,
        near_only_m: float = 0.0,
        upright_sigma_k: float | None = None,
        upright_accel_std: float | None = None,
        side_slice_m: float = 0.0,
        coasting: Coasting = NO_COASTING,
        view_margin_m: float = 0.0,
        jump_speed_std: float = 0.0,
        young_jump_frames: int = 0,
        jump_retake_m: float = 0.0,
        jump_retake_misses: int = 0,
        left_behind: LeftBehind | None = None,
        parting: Parting = NO_PARTING,
        velocity_faces: int = 0,
        narrow_by_points: bool = False,
        corners: CornerRule = NO_CORNERS,
        upright_by_points_m: float = 0.0,
        twins: Twins = NO_TWINS,
        learned: LearnedLabel | None = None,
    ) -> None:
        self.weights = weights
        self.accept_frames = accept_frames
        self.ghost_frames = ghost_frames
        self.accel_std = np.asarray(accel_std, dtype=np.float64)
        self.measurement_std = measurement_std
        self.range_noise_per_m2 = range_noise_per_m2
        self.velocity_var = np.asarray(initial_velocity_std, dtype=np.float64) ** 2
        self.volume = volume
        self.noise_adaptation = noise_adaptation
        self.smoothing = appearance_smoothing
        self.jumps = Jumps(jump_nis, jump_speed_std**2, young_jump_frames, jump_retake_m, jump_retake_misses)
        self.left_behind = left_behind or LeftBehind(0)
        self.fragment_margin = fragment_margin
        self.twins = twins
        self.parting = parting
        self.faces = FaceVelocity(velocity_faces, measurement_std)  # what the report blends in (report.py)
        self._parts: set[int] = set()  # this frame's parted pieces, by identity (_part)
        self.fragment_gap = fragment_gap
        self.standing = standing
        self.accept_misses = accept_misses
        self.reshape_m = reshape_m
        self.revive_restart_m = revive_restart_m
        self.merge_growth_m = merge_growth_m
        self.upright_speed_std = upright_speed_std
        self.side_slice_m = side_slice_m
        self.coasting = coasting
        self.view_margin_m = view_margin_m
        self.noise = kalman.ProcessNoise(
            self.accel_std,
            None if upright_accel_std is None else np.array([upright_accel_std, upright_accel_std, self.accel_std[2]]),
        )
        self.labeller = MotionLabeller(
            hysteresis,
            standing,
            measurement_std,
            frame_period_s,
            narrow_across_m,
            upright_sigma_k,
            near_only_m,
            narrow_by_points,
            corners,
            upright_by_points_m,
            learned,
        )
        self.corner_rule = corners
        self.corners = CornerHistory()  # the stereo stage's followed corners (common/corner_motion.py)
        self.counters: dict[str, int] = dict.fromkeys(COUNTERS, 0)
        self.tracks = TrackTable()
        self.ego = EgoVelocity()
        self.guard = FrameClock(frame_period_s, self.counters)  # which frames are taken (clock.py)
        self._next_id = 1
        self._clock = 0.0  # seconds of input processed: the time axis of the speed windows

    @classmethod
    def from_config(cls, cfg: Config) -> Tracker:
        t = cfg.tracker
        return cls(
            weights=Weights(t.w_position, t.w_color, t.w_size, t.w_density, t.gate, t.position_gate),
            accept_frames=t.accept_frames,
            ghost_frames=t.ghost_frames,
            hysteresis=Hysteresis(
                t.moving_on_mps, t.moving_off_mps, t.moving_sigma_k, t.moving_min_frames, t.moving_max_floor_m
            ),
            accel_std=(t.process_noise, t.process_noise, t.process_noise_z),
            measurement_std=t.measurement_noise,
            range_noise_per_m2=t.range_noise_per_m2,
            initial_velocity_std=(t.initial_speed_std, t.initial_speed_std, t.initial_vertical_speed_std),
            volume=cfg.volume.seen(),  # a cluster is cut where the mapper's lookahead ends
            noise_adaptation=t.noise_adaptation,
            appearance_smoothing=t.appearance_smoothing,
            frame_period_s=t.frame_period_s,
            jump_nis=t.jump_nis,
            fragment_margin=t.fragment_margin,
            fragment_gap=t.fragment_gap,
            standing=Standing(t.fragment_standing_m, t.upright_m, t.upright_thin_m, t.upright_alone_mps),
            accept_misses=t.accept_misses,
            reshape_m=t.reshape_m,
            narrow_across_m=t.narrow_across_m,
            revive_restart_m=t.revive_restart_m,
            merge_growth_m=t.merge_growth_m,
            upright_speed_std=t.upright_initial_speed_std,
            near_only_m=t.upright_near_only_m,
            upright_sigma_k=t.upright_sigma_k,
            upright_accel_std=t.upright_process_noise or None,
            side_slice_m=t.side_slice_m,
            coasting=Coasting(t.coast_merged_frames, t.coast_min_age, t.coast_max_speed_mps, t.coast_moving_frames,
                              t.coast_standing_frames),
            view_margin_m=t.view_margin_m,
            jump_speed_std=t.jump_speed_std,
            young_jump_frames=t.young_jump_frames,
            jump_retake_m=t.jump_retake_m,
            jump_retake_misses=t.jump_retake_misses,
            left_behind=LeftBehind(t.left_behind_frames, t.left_behind_share),
            parting=Parting(
                t.part_min_voxels,
                t.part_min_age,
                t.part_doubt,
                t.part_keep_cut,
                t.part_max_extent_m,
                t.part_standing_only,
            ),
            velocity_faces=t.velocity_faces,
            narrow_by_points=t.narrow_by_points,
            upright_by_points_m=t.upright_by_points_m,
            twins=Twins(t.twin_overlap_m, t.twin_mps, t.twin_wide_m, t.twin_near_m),
            learned=learned_label(
                t.motion_model,
                t.motion_model_on,
                t.motion_model_off,
                t.motion_model_corners,
                t.motion_model_young_on,
                t.motion_model_young_sigma_mps,
            ),
            corners=corner_rule(t),
        )

    def process(self, clusters: Clusters, ego: EgoMotion) -> Obstacles:
        """One frame of clusters (world frame) and its egomotion -> every track as an obstacle."""
        if clusters.beyond:  # the lookahead's are followed as the volume's are (VolumeConfig.lookahead_m)
            clusters = dataclasses.replace(clusters, clusters=[*clusters.clusters, *clusters.beyond], beyond=[])
        stale, new_world = self.guard.stale(clusters)
        if new_world:
            self.tracks = TrackTable()
        if stale:
            return obstacles_of(self.tracks, self.ego.velocity, clusters, ego, self.faces, self.corner_rule)
        dt, elapsed = self.guard.step(clusters)
        self._clock += dt
        if self.corner_rule.samples > 0:
            self.corners.update(
                clusters.keypoint_ids, clusters.keypoints, clusters.keypoint_std, self._clock, clusters.world_epoch
            )
        trusted = self._observe_ego(ego)
        pose = self._placement_pose(clusters, ego)
        self._predict(dt)
        sight = Sight(pose[0:3, 3], clusters.voxel_edge)
        self._parts = set()
        pieces = self._gather(clusters, sight, pose)
        obs, stacked = self._observe(pieces, pose, clusters.voxel_edge, clusters.view)
        parted = np.zeros(len(obs), dtype=bool)
        if self._parts:
            parted[:] = [id(pieces[int(i)]) in self._parts for i in obs.index]
        r = self._cluster_cov(obs, pose, clusters.voxel_edge) + part_covariance(obs.extent, parted, self.parting.doubt)
        rows, cols = self._associate(obs, r)
        self.tracks.parted[:] = False
        self.tracks.parted[rows] = parted[cols]
        if trusted:
            self._correct(rows, obs.take(cols), r[cols])
        piece_of = dict(zip(rows.tolist(), [pieces[k] for k in obs.index[cols].tolist()], strict=True))
        track_corners(
            self.tracks, self.corners, self.corner_rule, rows, cols, stacked, clusters.voxel_edge, pose[0:2, 3]
        )
        if trusted:
            slid = self.left_behind.slid(
                self.tracks.ids, rows, cols, obs, pieces, self.tracks.moving, clusters.voxel_edge
            )
            self.counters["slid"] += restart_from_rest(self.tracks, slid, self.velocity_var)
            self.counters["corner_restarts"] += restart_revived(self.tracks, self.corner_rule, rows, self.velocity_var)
            correct_by_corners(self.tracks, self.corner_rule)
        self._advance_queues(rows, elapsed, piece_of, sight)
        fresh = np.ones(len(obs), dtype=bool)
        fresh[cols] = False
        self._spawn(obs.take(fresh), r[fresh], parted[fresh])
        if trusted:
            moving = self.labeller.label(self.tracks, clusters.voxel_edge, pose[0:2, 3], len(clusters.keypoint_ids) > 0)
            # a part's motion is partly where the parting drew its edge: it may keep a label, not give one
            self.tracks.moving = moving & (self.tracks.moving | ~self.tracks.parted)
            self.tracks.moving &= ~wider_twins(self.tracks, self.twins)
        return obstacles_of(self.tracks, self.ego.velocity, clusters, ego, self.faces, self.corner_rule)

    # ------------------------------------------------------------------ input

    def _observe_ego(self, ego: EgoMotion) -> bool:
        """Update the vehicle's velocity; whether this frame's world placement can be trusted."""
        trusted = bool(ego.valid) and bool(np.isfinite(ego.pose).all())
        if not trusted:
            self.counters["ego_invalid"] += 1
        self.ego.observe(ego.pose, trusted, ego.world_epoch, ego.stamp_ns)
        return trusted

    def _gather(self, clusters: Clusters, sight: Sight, pose: NDArray) -> list[Cluster]:
        """The clusters with the pieces of one known object merged (fragments.py)."""
        t = self.tracks
        known = t.queue != ACCEPTANCE
        if self.fragment_margin < 0.0 or not known.any():
            return clusters.clusters
        shift = (t.x[known, 0:3] + t.offset[known]) - t.centroid[known]
        lo, hi = t.bbox_min[known] + shift, t.bbox_max[known] + shift
        margin, edge = self.fragment_margin, clusters.voxel_edge
        speed = np.hypot(t.x[known, 3], t.x[known, 4])
        gathered = gather(clusters.clusters, lo, hi, margin, edge, self.fragment_gap, self.standing, sight, speed)
        return self._part(gathered, edge, pose, clusters.view)

    def _part(self, clusters: list[Cluster], edge: float, pose: NDArray, view: NDArray) -> list[Cluster]:
        """Clusters two known standing tracks lie in, parted between them (parting.py)."""
        if self.parting.min_voxels <= 0:
            return clusters
        whole = cut_by_view(pose, edge, view, self.view_margin_m) if self.parting.keep_cut else None
        out, self._parts, n = part_tracked(clusters, self.tracks, self.parting, edge, whole)
        self.counters["parted"] += n
        return out

    def _observe(
        self, clusters: list[Cluster], pose: NDArray, edge: float, view: NDArray
    ) -> tuple[Observations, Footprint]:
        obs, stacked, dropped = observe(clusters, pose, edge, view, self.view_margin_m)
        self.counters["nan_clusters"] += dropped
        if len(obs) == 0:
            self.counters["empty_frames"] += 1
        return obs, stacked

    # ------------------------------------------------------------------ the paper's steps

    def _predict(self, dt: float) -> None:
        t = self.tracks
        if len(t):
            t.x, t.p = kalman.predict(t.x, t.p, kalman.transition(dt), self._process_noise(dt))

    def _process_noise(self, dt: float) -> NDArray:
        """(6, 6), or (n, 6, 6) when an upright track (a person) may change speed faster than a car.

        A walker starts and stops within a second: with a car's 1 m/s^2 a track that began on a
        walker waiting at the kerb took 8-10 frames to follow him across (synthetic crossing-s2;
        docs/results/tracking.md, "Session 22").
        """
        q, q_upright = self.noise.over(dt)
        if q_upright is None:
            return q
        upright = self.standing.upright(self.tracks.bbox_max - self.tracks.bbox_min)
        return np.where(upright[:, None, None], q_upright[None], q[None])

    def _associate(self, obs: Observations, r: NDArray) -> tuple[NDArray, NDArray]:
        t = self.tracks
        extent = t.bbox_max - t.bbox_min
        var = position_variance(t.p[:, 0:3, 0:3], np.maximum(t.nis, 1.0), extent, r, obs.extent)
        d = distance_matrix(
            self.weights, var,
            t.x[:, 0:3] + t.offset, t.rgb, t.hsl, t.extent, t.density,
            obs.centroid, obs.rgb, obs.hsl, obs.extent, obs.density,
        )  # fmt: skip
        rows, cols = greedy_pairs(d, self.weights.gate)
        rows, cols = self.jumps.unpair_young(rows, cols, t, obs.followed, r)
        paired = len(rows)
        rows, cols = self.jumps.retake(rows, cols, t, obs.centroid)
        self.counters["retaken"] += len(rows) - paired
        return rows, cols

    @staticmethod
    def _placement_pose(clusters: Clusters, ego: EgoMotion) -> NDArray:
        """The vehicle pose the clusters were placed with: the egomotion's, else the mapper's."""
        for pose in (ego.pose, clusters.ego_pose):
            if np.isfinite(pose).all():
                return np.asarray(pose, dtype=np.float64)
        return np.eye(4)

    def _cluster_cov(self, obs: Observations, pose: NDArray, voxel_edge: float) -> NDArray:
        """How far each centroid can be trusted from the cluster alone (measurement.py)."""
        r = stereo_covariance(obs.followed, pose[0:3, 3], self.measurement_std, self.range_noise_per_m2)
        r += cut_covariance(obs.bbox_min, obs.bbox_max, pose, self.volume, voxel_edge, self.side_slice_m)
        across = obs.cut & (obs.side == 1)  # straddling the line of sight: cut sideways
        if across.any():
            r[across] += view_cut_covariance(obs.extent[across], pose)
        return r

    def _correct(self, rows: NDArray, obs: Observations, r: NDArray) -> None:
        """Kalman correction of the associated tracks with their clusters' centroids."""
        if len(rows) == 0:
            return
        t = self.tracks
        turn_sides(t, rows, obs)
        turn_ends(t, rows, obs)
        # a walker's or a pole's box changes with the fringe of stereo smear around it, which
        # hardly moves the middle range of its points that a narrow cluster is followed at
        # (anchor.py): its extent change is no noise on that point (docs/results/tracking.md,
        # "Session 20"; without the upright test KITTI's roadside structures were called moving)
        extent_before = t.bbox_max[rows] - t.bbox_min[rows]
        seen = visibility_covariance(obs.extent, extent_before)
        seen[obs.narrow & self.standing.upright(obs.extent)] = 0.0
        r = r + seen
        # adaptive noise: a cluster whose centroid keeps jumping by more than its covariance says
        # (a fragment of a split object, changing membership) is believed that much less
        x_before, p_before, point = t.x[rows], t.p[rows], obs.followed
        nis = kalman.normalised_innovation(x_before, p_before, point, r)
        r = r * np.maximum(t.nis[rows], 1.0)[:, None, None]
        x, p = kalman.update(x_before, p_before, point, r)
        # a centroid further off than the filter allows is a cluster that changed (split, merge,
        # another face in view), not the object moving: re-anchor (jumps.py)
        jump = self.jumps.of(nis)
        # a ghost, or a track that coasted (queues.py), found again metres from where it was
        # predicted may be another object: one seen a few frames, its speed unknown, takes the step
        # as speed, and a window spanning the gap agrees; the window starts again (synthetic
        # urban-s1: a standing walker called moving at 6 m/s)
        off = np.linalg.norm((point - x_before[:, 0:3])[:, 0:2], axis=1)
        refound = (t.misses[rows] > 0) & (off > self.revive_restart_m) & (self.revive_restart_m > 0.0)
        self.jumps.re_anchor(jump, x, p, x_before, p_before, point, r)
        # and the faces of the old shape say nothing about the new one's motion, even where the
        # filter let a change of extent pass as visibility (a parked car leaving the blob it was
        # merged into); a track already moving keeps its faces, which its label stays on
        extent_step = np.abs(obs.extent - extent_before)[:, 0:2].max(axis=1)
        reshaped = (extent_step > self.reshape_m) & ~t.moving[rows]
        # a part's faces are where the parting drew its edges: the window starts again after one
        motion_window.restart(t.window_n, rows[jump | reshaped | refound | (t.parted[rows] & ~t.moving[rows])])
        motion_window.push(t.window, t.window_t, t.window_n, rows, obs.anchor, self._clock)
        motion_window.push_points(t.window_far, rows, obs.anchor + obs.far)
        t.nis[rows] += self.noise_adaptation * (np.where(jump, t.nis[rows], nis) - t.nis[rows])
        t.x[rows], t.p[rows] = x, p
        # a cluster suddenly wider than the object has been (its smoothed extent) has taken in a
        # neighbour: the obstacle keeps its own box and centroid, carried by the filter, rather
        # than the merged pair's (slope-s10: a lead car reported 2.2 m sideways, on an oncoming
        # car's box, for one frame; docs/results/tracking.md, "Session 21")
        own = ~self._swallowed(rows, obs)
        kept = rows[own]
        t.offset[kept] = obs.centroid[own] - x[own, 0:3]
        t.centroid[kept], t.bbox_min[kept], t.bbox_max[kept] = obs.centroid[own], obs.bbox_min[own], obs.bbox_max[own]
        t.volume[kept] = obs.volume[own]
        follow_appearance(t, rows, obs, self.smoothing)

    def _swallowed(self, rows: NDArray, obs: Observations) -> NDArray:
        """Which tracked rows' clusters outgrow their smoothed extent by over ``merge_growth_m`` (x or y)."""
        t = self.tracks
        if self.merge_growth_m <= 0.0:
            return np.zeros(len(rows), dtype=bool)
        growth = (obs.extent - t.extent[rows])[:, 0:2].max(axis=1)
        return (growth > self.merge_growth_m) & (t.queue[rows] == TRACKED)

    def _advance_queues(self, rows: NDArray, elapsed: int, piece_of: dict[int, Cluster], sight: Sight) -> None:
        seen = np.zeros(len(self.tracks), dtype=bool)
        seen[rows] = True
        held = inside_known(self.tracks, seen, piece_of, sight, self.fragment_margin, self.standing)
        t = self.tracks
        coast = coasts(t, seen, elapsed, self.coasting, self.standing.upright(t.bbox_max - t.bbox_min))
        keep = advance(t, seen, elapsed, self.accept_frames, self.ghost_frames, held, self.accept_misses, coast)
        self.counters["tracks_dropped"] += int((~keep).sum())
        self.tracks.keep(keep)

    def _initial_p(self, obs: Observations, r: NDArray) -> NDArray:
        """A new track's covariance: position as trusted as its cluster, velocity all but unknown.

        A narrow upright cluster is a walker, a cyclist or a pole, none faster than ~7 m/s: with
        the prior of a car, its second cluster's change of shape (a smear piece, then the walker)
        was read as 5-10 m/s and stayed for 5-10 frames (docs/results/tracking.md, "Session 21").
        """
        p = kalman.initial_covariance(r, self.velocity_var)
        if self.upright_speed_std is not None:
            upright = self.standing.upright(obs.extent) & obs.narrow
            p[upright, 3, 3] = p[upright, 4, 4] = self.upright_speed_std**2
        return p

    def _spawn(self, obs: Observations, r: NDArray, parted: NDArray) -> None:
        """New acceptance tracks (``_initial_p``)."""
        n = len(obs)
        if n == 0:
            return
        self.counters["tracks_born"] += n
        ids = np.arange(self._next_id, self._next_id + n, dtype=np.int64)
        self._next_id += n
        self.tracks.extend(born(ids, obs, self._initial_p(obs, r), self._clock, parted))
