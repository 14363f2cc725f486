"""One typed configuration tree: the paper's values in code, then a file, then ``--set``.

Each section is a dataclass; constructors of the cores take the section they need
(``StereoDepth.from_config(cfg)``). The effective tree goes into every recording's metadata,
so a result can always be traced to the settings that made it. Reading a file, ``--set`` and a
recording's stored tree into it is common/config_loading.py's.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from typing import Any


@dataclass
class BusConfig:
    """How a process joins Zenoh: peer on loopback by default, client towards a router when deployed."""

    mode: str = "peer"  # peer | client | router
    listen: list[str] = field(default_factory=list)
    connect: list[str] = field(default_factory=list)
    vehicle: str = "ego"
    shared_memory: bool = False  # without a zenoh_config file; with one, the file decides
    multicast_scouting: bool = False
    user: str = ""  # usrpwd authentication (client side)
    password: str = ""
    zenoh_config: str = ""  # a full Zenoh JSON5 file, applied before the fields above
    close_linger_s: float = 0.5  # a stage leaves the bus no sooner than this after its last put (in flight)


@dataclass
class VolumeConfig:
    """Volume of interest in the vehicle frame (the paper: 28.7 x 16.4 x 3.5 m ahead)."""

    x_min: float = 0.0
    x_max: float = 28.7
    y_half: float = 8.2
    z_min: float = 0.0
    z_max: float = 3.5
    # the stages see and follow this far (m) beyond x_max, so that an object coming into range arrives
    # with a track and a speed, and one at the far end is not cut there; what lies beyond x_max is
    # still outside the volume: clusters there are passed on apart (Clusters.beyond), evaluation
    # scores nothing there (docs/results/tracking.md, "Session 52")
    lookahead_m: float = 1.5  # 0: the paper's, the volume alone (3.0 measured)

    def seen(self) -> VolumeConfig:
        """The volume the stages look into: this one, lengthened by ``lookahead_m``."""
        return dataclasses.replace(self, x_max=self.x_max + self.lookahead_m, lookahead_m=0.0)


@dataclass
class StereoConfig:
    """Semi-global matching and reprojection (step 1); defaults measured on KITTI raw and Middlebury.

    Two-level scheme: a half-resolution pass covers the whole range down to ``min_depth_m`` (both
    views, checked against each other); the full-resolution pass covers the first
    ``fine_disparities`` (far range, where a pixel of disparity is worth the most metres), checked
    against its own right view. docs/results/stereo.md has the measurements behind the defaults.
    """

    num_disparities: int = 0  # 0 = from the frame's calibration: fx * baseline / min_depth_m
    min_depth_m: float = 2.0  # nearest obstacle the search range must reach
    fine_disparities: int = 64  # full-resolution range; beyond it the half-resolution pass measures
    block_size: int = 3
    p1_factor: int = 12  # P1 = p1_factor * channels * block_size^2
    p2_factor: int = 48
    uniqueness: int = 10  # full-resolution pass
    coarse_uniqueness: int = 25  # half-resolution pass, whose pixels also fill holes
    speckle_window: int = 100
    speckle_range: int = 2
    lr_check: str = "full"  # full (right view at full resolution) | coarse (at half: faster, less dense) | none
    lr_max_diff_px: float = 1.0  # pixels of the coarser of the two disparity maps compared
    fill_support_px: int = 5  # holes take the coarse value if within the fine ones this near (px); 0 = off
    hidden_fill_max_px: int = 12  # holes the right camera cannot see take the adjacent surface, this far (px); 0 = off
    hidden_fill_colour_step: int = 10  # ... but not across an edge: a step of more grey levels than this
    min_texture: float = 4.0  # mean |grey x-gradient| (9 px square) below which fine values need the coarse's agreement
    sky_window_px: int = 5  # flat pixels (this square) joined to the top row get no disparity (sky.py); 0 = off
    sky_max_gradient: float = 8.0  # ... flat: mean |grey x-gradient| + |y-gradient| under this
    sky_gap_colour: float = 20.0  # ... and flat regions of its colour (grey levels) under a gantry (sky.py); 0 = off
    # ... and pixels of its colour this near the open sky in a slot between two depths (sky.py); 0 = off. 2 since
    # session 69: slope-s7's phantom clusters 0.125 -> 0.075 a frame, unseen seeds unchanged (docs/results/voxel.md)
    sky_fringe_px: int = 2
    # ... and pixels of its colour this far under the open sky holding another depth than what lies below them
    # (sky.py); 0 = off. 4 since session 70: hanging's sky over the horizon no longer hangs under its signs
    sky_underside_px: int = 4
    contrast_span: float = 160.0  # a dimmer pair (1-99 % grey levels) gets P1, P2 as if it spanned this; 0: off
    pre_filter_cap: int = 63  # lower caps gain 0.3 points of D1 but lose sub-pixel precision
    mode: str = "3way"  # 3way | sgbm | hh | hh4
    # > 1: match the pair widened this many times, every pixel setting in the widened pixels (matcher.py). The
    # whole pair widened twice on the synthetic camera: urban one-cluster 89.4 -> 93.0 %, at 1.86 x the stage's
    # time; on KITTI raw density 91.1 -> 86.9 % (docs/results/voxel.md, "Session 64"); 1: not widened
    upsample_x: int = 2
    # with upsample_x > 1: 0 widens the whole pair; over 0, only the box where the volume beyond this range
    # (m) projects, the unwidened disparity kept in its holes; a dim pair not at all (far_band.py; session 65).
    # 18 since session 67 (15: as good, its pass 1.3-1.5 x as long; 20, 22: held-out one-cluster under 90)
    upsample_beyond_m: float = 18.0
    color_matching: bool = False  # False = match grey images (measured better and faster)
    fill_left_border: bool = True  # pad on the left so the first columns get a disparity too
    decimation: int = 1  # keep every n-th point in x and y
    min_points_depth_m: float = 0.5
    below_volume_m: float = 1.0  # keep points this far below volume.z_min: the road for the mapper
    disparity_offset_px: float = 0.0  # a rig's disparity bias, added before depth (KITTI: as odometry's)
    disparity_edge_px: float = 0.0  # plus this times ((u - cx) / fx)^2, towards the image sides
    keypoints: int = 8000  # corners followed from frame to frame with their disparity (keypoints.py); 0 = off
    # ... at most one new one per square cell of this side: 4 puts 2.5 times the corners on a cluster's
    # voxels as 8 did (3000 corners until session 48; docs/results/stereo.md, "Session 48")
    keypoint_cell_px: int = 4
    keypoint_disparity_std_px: float = 0.3  # ... whose disparity is this sure (one sigma): their range's doubt
    subpixel_iterations: int = 3  # Lucas-Kanade steps re-estimating SGM's sub-pixel part; 0 = off
    subpixel_window: int = 11  # their Gaussian window (px, odd)
    subpixel_span_px: float = 1.5  # ... used only where the window's matched disparities span at most this
    subpixel_max_step_px: float = 0.75  # a larger correction keeps the matcher's value
    subpixel_max_disparity_px: float = 32.0  # ... and so does any pixel over this (0.15 px is < 0.5 % of its depth)
    ramp_step_px: float = 1.0  # > 0: pixels between two plateaus this far apart moved or left out (ramps.py); 0: off
    ramp_reach_px: int = 4  # ... plateaus this many columns to either side (measured 2-5)
    ramp_width_px: int = 3  # ... each the mean of this many columns
    ramp_margin_px: float = 0.2  # ... and a pixel this near either plateau's disparity is that surface's own
    ramp_flat_share: float = 0.0  # ... each plateau changing by at most this share of the step (0.15 to drop); 0: off
    ramp_snap_ratio: float = 0.3  # > 0: ramp pixels moved onto the plateau clearly nearer in colour (by this factor);
    # 0: left out of the cloud. Session 46: 0.3 kept, 0.5 and leaving out measured (docs/results/voxel.md)


@dataclass
class OdometryConfig:
    """Stereo visual odometry with four-image circular matching (step 2)."""

    max_features: int = 2000
    fast_threshold: int = 20
    min_corners: int = 1000  # below this many corners the FAST threshold halves (dark, low-contrast frames)
    min_fast_threshold: int = 4
    feature_cell_px: int = 16  # corners are capped per grid cell so they cover the image
    features_per_cell: int = 4
    match_radius_px: float = 200.0  # temporal search window without a motion prior
    predicted_radius_px: float = 30.0  # temporal search window around the predicted position
    coarse_features: int = 800  # strongest corners per image for the wide search without a prior
    coarse_cell_px: int = 16  # at most one of them per cell of this size
    row_tolerance_px: float = 1.0  # rectified epipolar constraint for stereo matches
    bucket_px: int = 50  # circle matches kept per bucket for the motion estimate
    bucket_matches: int = 16
    subpixel_window: int = 11  # Lucas-Kanade refinement window (pixels)
    subpixel_stereo: bool = True  # LK-refine disparities too (off: integer disparities, 0.6 % less scale on KITTI)
    warp_temporal: bool = True  # refine temporal matches with windows warped by the expected motion (road looming)
    warp_ground_m: float = 0.3  # points this near the road are warped as road, others as facing the camera
    disparity_offset_px: float = 0.0  # added to every disparity: a rig's bias measured against lidar (KITTI: 0.16)
    disparity_edge_px: float = 0.0  # plus this times ((u - cx) / fx)^2, towards the sides (KITTI: 1.3; docs/results)
    usable_width: float = 1.0  # share of the image width, centred on cx, whose matches estimate motion
    ransac_iterations: int = 200
    ransac_threshold_px: float = 1.5
    symmetric: bool = False  # also refine on backward reprojection (measured: no gain on KITTI)
    robust_px: float = 0.5  # Cauchy scale of the final refinement's weights (0 = plain least squares)
    min_inliers: int = 20
    max_disparity: float = 256.0
    min_disparity: float = 1.0
    max_lost_frames: int = 5  # predicted frames bridged before the world is re-anchored
    seed: int = 0  # RANSAC sampling, so a run is repeatable
    fuse_ins: bool = False  # fuse the vehicle's speed and yaw rate (vehicle/motion) per frame (ins.py)
    ins_speed_std_mps: float = 0.05  # their noise, one sigma: an INS or wheel odometry's speed ...
    ins_yaw_rate_std_dps: float = 0.05  # ... and its gyro (deg/s)
    ins_vision_scale_std: float = 0.01  # vision's step length error its covariance does not show (share)
    ins_vision_yaw_std_dpm: float = 0.005  # ... and its yaw error (deg per metre travelled)


@dataclass
class VoxelConfig:
    """Voxel map and colour flood-fill clustering (steps 3 and 4)."""

    edge: float = 0.25
    epsilon: float = 0.4  # Eq. 1 threshold on normalised colours (measured: 0.25..0.45)
    circular_hue: bool = False  # hue as an angle (chroma-weighted mean, short way round); off: as a number
    min_cluster_voxels: int = 20  # smaller clusters are merged into a neighbour or dropped (measured: 4..24)
    min_density: float = 0.02  # voxels / bounding-box volume (in voxels)
    aggregate_in_turn_m: float = 0.0  # nearer than this (m), small pieces add up (Alg. IV-B.2 in turn); 0 = off
    min_points_per_voxel: int = 8  # points a voxel gathered before it is clustered (measured: 2..8)
    keep_frames: int = 0  # 0 = the paper: a voxel without points this frame is removed (1: trails merge objects)
    ground: str = "terrain"  # flat (z > ground_clearance) | terrain (height above local road)
    ground_clearance: float = 0.2
    terrain_slice: float = 1.0  # m of x per slice of the terrain height profile
    terrain_max_grade: float = 0.15  # steepest road grade (and grade change per slice) followed
    join_share: float = 0.3  # clusters joined as parts of one object when this share of one links to the other
    bridge_voxels: int = 3  # a gap along the line of sight up to this many voxels still links two parts
    step_bridge_voxels: int = 4  # same, one layer up and away or down and nearer, seen from both parts (measured 0-8)
    points_range_m: float = 15.0  # beyond this range min_points_per_voxel falls with range squared (0 = fixed)
    min_points_far: int = 2  # ... but never below this
    join_min_voxels: int = 6  # smallest parts joined into one object (0 = min_cluster_voxels; 8 until session 46)
    # which linked parts are one object: "builtin" (trees trained on tuning runs, join_model.py), a model
    # file, or "" for join_share's rule alone (until session 53; docs/results/voxel.md, "Session 53")
    join_model: str = "builtin"
    join_probability: float = 0.8  # ... the model's chance above which linked parts are joined, rule or not
    join_veto: float = 0.5  # ... and below which the rule's joins are not made (0: the model only adds;
    # over 1: the model alone decides)
    cut_tall_m: float = 2.8  # in a cluster this tall, a patch of columns ending below cut_low_m is cut off (0 = off)
    cut_low_m: float = 2.0  # measured 2.0..2.5 and 2.5..3.0 m tall: within 1 point on urban seeds 1-2
    cut_min_voxels: int = 12
    group_dense_share: float = 0.3  # columns with this share of the densest one's points: people (0 = off; 0.2, 0.3)
    group_min_voxels: int = 40  # ... a cluster is cut, one per person, if each keeps this many (0, 20, 30, 40)
    apart_min_corners: int = 5  # parts each with this many followed corners may be kept apart (0 = never; apart.py)
    apart_across_mps: float = 0.4  # ... when their corners' speeds across the line of sight differ by more than this
    apart_sigma_k: float = 2.5  # ... and by more than this many of their joint doubts
    apart_still_mps: float = 0.2  # ... and one part is slower than this across it (0 = either may move)
    apart_samples: int = 3  # frames a corner must be followed for its velocity


@dataclass
class TrackerConfig:
    """Greedy association, three queues and a 6-D Kalman filter (step 5).

    Chosen by replaying the tracker alone over the clusters and egomotion of `stereovox process`
    runs of synthetic urban, crossing and overtake, seeds 1-2 (60 frames each), and scoring with
    `stereovox evaluate`'s own code; docs/results/tracking.md has the figures on seeds 7-8 and
    how they were made. What moved the figures (urban moving TP/FP/FN, seeds 1-2 pooled):
    following the faces in view instead of the centroid (services/tracker/anchor.py), merging
    the pieces of a known object (``fragment_margin``), re-anchoring on jumps (``jump_nis``) and
    accepting after 2 frames took 56/20/23 % to 73/5/22 %. The weights were checked against a
    logistic fit of same-object vs other-object (track, cluster) pairs within 3 m (AUC 0.90 with
    these, 0.91 fitted: colour 1, size 4.6, density 0); the fitted weights scored no better in
    the replay, so the earlier ones stay. Every other field here moved the figures by less than
    the difference between two seeds when varied by a factor of 1.5-2 either way. Later, on the
    area-sampled renders (40 frames): merging only pieces whose boxes touch (``fragment_gap``)
    freed walkers held inside a blob's old box (services/tracker/fragments.py).
    """

    w_position: float = 1.0
    w_color: float = 2.0
    w_size: float = 0.5
    w_density: float = 0.5
    gate: float = 3.0  # association threshold on the weighted distance
    position_gate: float = 3.5  # pairs further apart than this many standard deviations never associate
    accept_frames: int = 2  # 3: urban moving TP 3-6 points lower (pedestrians seen intermittently)
    accept_misses: int = 0  # frames in a row a new track may go unseen before it is dropped (paper: 0)
    ghost_frames: int = 6  # 5 until session 44 (scripts/sweep_tracker.py: 7 let KITTI 0001 call 4 frames moving)
    moving_on_mps: float = 0.5  # evaluation: moving >= 1.0 m/s, stationary < 0.3 m/s (0.7 until 24, 0.55 until 44)
    moving_off_mps: float = 0.4
    moving_sigma_k: float = 1.5  # the label follows speed - k * speed std (minus the box-growth slide)
    moving_min_frames: int = 3  # frames of track before it may be called moving (4 until session 45)
    moving_max_floor_m: float = 1.0  # a cluster whose lowest voxel is higher above the road never turns moving; 0: off
    process_noise: float = 1.0  # horizontal acceleration std (m/s^2)
    process_noise_z: float = 0.1  # vertical acceleration std (m/s^2): obstacles stay on the road
    upright_process_noise: float = 2.0  # ... horizontal, of an upright track: people start and stop (0 = as others)
    measurement_noise: float = 0.15  # centroid std (m) across the viewing ray, and near
    range_noise_per_m2: float = 0.0005  # added std along the ray per squared metre of range (stereo)
    side_slice_m: float = 1.75  # a cluster reaching in from a side of the volume by less: a slice, unsure in x too
    initial_speed_std: float = 5.0  # horizontal velocity std of a new track (m/s)
    initial_vertical_speed_std: float = 0.3  # its vertical velocity std (m/s)
    upright_initial_speed_std: float = 3.5  # ... a new narrow upright one's (walker, cyclist, pole)
    noise_adaptation: float = 0.0  # weight of the newest normalised innovation in a track's noise scale (0 = off)
    appearance_smoothing: float = 0.5  # weight of the newest cluster in a track's colour/size/density
    frame_period_s: float = 0.1  # time step when stamps cannot give one
    jump_nis: float = 7.8  # innovation (squared Mahalanobis, 3 dof; 7.8 = chi2 95 %) that re-anchors, not corrects
    jump_speed_std: float = 3.0  # ... and doubts the velocity it keeps by this much more (m/s, horizontal); 0 = not
    left_behind_frames: int = 3  # a track whose footprint this many frames back others now hold slid; 0 = off
    left_behind_share: float = 0.5  # ... if they hold more than this share of it: it starts again from rest
    young_jump_frames: int = 0  # ... a track younger than this (frames) is not paired with such a cluster; 0 = off
    jump_retake_m: float = 1.5  # a moving track left unpaired takes a cluster left over this near (m); 0 = off
    jump_retake_misses: int = 2  # ... if unseen at most this many frames before (1.0 m or 0 frames: fewer retaken)
    velocity_faces: int = 6  # the reported velocity blends in the line through this many faces or more; 0 = off
    part_min_voxels: int = 0  # a cluster two known tracks lie in is parted, pieces of this many voxels or more; 0 = off
    part_min_age: int = 5  # ... between tracks at least this old (frames)
    part_doubt: float = 0.5  # ... and a part's centroid doubted by this share of its extent (std, per axis)
    part_keep_cut: bool = True  # ... but never a cluster the image's side edge cuts
    part_max_extent_m: float = 6.0  # ... and only between tracks whose boxes are at most this long (x and y)
    part_standing_only: bool = True  # ... labelled stationary (measured: the best of the variants, tracking.md)
    fragment_margin: float = 0.25  # clusters in a known track's predicted box grown by this (m) merge; < 0: off
    fragment_gap: float = 0.1  # ... only pieces whose boxes touch (chained by gaps up to this, m); < 0: any
    fragment_standing_m: float = 0.3  # ... two reaching this near their floor (m) only if footprints touch; < 0: off
    upright_m: float = 1.2  # a cluster this tall (m) and at most upright_thin_m across in x or y is a person or a
    upright_thin_m: float = 1.3  # pole: two standing are never gathered, a narrow one gets no extent noise; 0: off
    upright_alone_mps: float = 3.0  # ... nor one such with any standing piece, by a track slower than this; 0: off
    upright_sigma_k: float = 0.75  # ... and an upright track turns moving at this many speed sigmas, not moving_sigma_k
    upright_near_only_m: float = 4.0  # ... and if no longer (m, x and y), its near face alone confirms it; 0: off
    reshape_m: float = 3.0  # box grown or shrunk by more (m, x or y): a not-yet-moving track's speed window restarts
    narrow_across_m: float = 2.0  # narrower across its line of sight (m): labelled by its speed across if surer; 0: off
    # ... and only its growth across the line of sight counts as slide (labelling.py)
    narrow_by_points: bool = True  # ... narrow by its points (width across, core's depth along), not its box
    # two moving tracks at one velocity (within twin_mps): the one wider across the line of sight is not moving if
    # their boxes overlap by twin_overlap_m (x and y; < 0: never) and it is twin_wide_m wide, the other narrower;
    # or whatever their widths if their centres are within twin_near_m (< 0: never). Session 54, twins.py
    twin_overlap_m: float = 0.0
    twin_mps: float = 0.75
    twin_wide_m: float = 1.5
    twin_near_m: float = 0.4
    upright_by_points_m: float = 0.0  # this tall (m), upright (upright_sigma_k) also if thin by its points; 0: off
    revive_restart_m: float = 1.0  # a ghost found this far (m) from its prediction restarts its speed window; 0: off
    merge_growth_m: float = 2.0  # cluster wider by more (m) than its track's smoothed extent: box kept; 0: off
    coast_merged_frames: int = 3  # an upright track unseen inside a seen tracked box stays tracked this long; 0: off
    coast_min_age: int = 8  # ... if this many frames old (measured 0: a young track's wrong velocity coasted too)
    coast_max_speed_mps: float = 5.0  # ... and no faster (a car's rear is upright too; 3 measured the same)
    coast_moving_frames: int = 2  # ... labelled moving, it coasts this long, merged or not (3 measured); 0: off
    coast_standing_frames: int = 1  # ... labelled standing, this long, merged or not (2, 3 measured alike); 0: off
    view_margin_m: float = 0.5  # a cluster this near (m) the image's side edge: followed at its far end (1.0: alike)
    corner_samples: int = 3  # a corner's velocity needs this many frames of it (4 until session 48; 5 measured); 0: off
    corner_min_count: int = 4  # a track's corners have an opinion when it holds this many (5 until session 43)
    corner_on_mps: float = 1.0  # ... and their median speed, less its doubt, above this turns it moving
    corner_sigma_k: float = 1.75  # ... that doubt taken this many times (2.0 until 44; 1.5: KITTI 1 false frame)
    corner_still_mps: float = 1.0  # ... below this, plus its doubt, keeps a track standing (0.8, 1.2 alike; 0: off)
    corner_update_gate: float = 9.0  # their velocity corrects the filter's within this 2-D NIS (4 measured); 0: off
    corner_update_floor_mps: float = 0.2  # ... as a measurement at least this doubtful (m/s)
    corner_confirm_count: int = 2  # this many, sure of a speed, may confirm the filter's (3, 5 measured); 0: off
    corner_blend_count: int = 2  # this many are blended into a moving track's reported velocity (5 until session 42)
    corner_restart_count: int = 4  # a standing ghost found again with this many beyond its filter's gate restarts
    corner_across_std_m: float = 0.05  # a corner's place across the line of sight (m; 0.03, 0.1 measured); 0: off
    # a piece's corners' velocity carried from their lines' middle to this frame by their median acceleration
    # (common/corner_lead.py) where it is this many sigmas sure (2, 4 alike; 0: off) ...
    corner_lead_sigmas: float = 3.0
    corner_lead_min_mps: float = 2.0  # ... on a piece whose corners read this or more (1.0: more false frames)
    corner_lead_samples: int = 6  # ... from the corners followed this many frames (5, 7 alike)
    # a group of this many corners or more on a track moving one way across the line of sight at corner_mover_mps
    # (their median), within corner_mover_tol_mps of it, each at corner_mover_from_mps or more, lying within
    # corner_mover_width_m across it, turns the track moving while its filter's speed is over corner_mover_filter_mps
    # (a walker sharing a wall's cluster; keypoint_motion.py); 0: off
    corner_mover_count: int = 8
    corner_mover_mps: float = 0.4
    corner_mover_from_mps: float = 0.35
    corner_mover_tol_mps: float = 0.25
    corner_mover_width_m: float = 0.75
    corner_mover_filter_mps: float = 0.5
    # moving or stationary judged by trees (services/tracker/motion_model.py): "builtin" (trained on tuning
    # runs), a model file, or "" for the rule (labelling.py); a track turns moving when their chance clears
    # motion_model_on and stays moving while it clears motion_model_off
    motion_model: str = "builtin"
    motion_model_on: float = 0.9
    motion_model_off: float = 0.5
    motion_model_corners: bool = True  # ... and corners sure of its pace turn a track moving too, as in the rule
    # ... and a frame younger than moving_min_frames when their chance clears this (1: never; session 68: 0.95-0.98
    # alike on the tuning runs, 0.97 the fewest false frames there)
    motion_model_young_on: float = 0.97
    motion_model_young_sigma_mps: float = 1.0  # ... if its filter knows its speed to this (a car: 5.6 +- 3.4 m/s)


@dataclass
class RecorderConfig:
    """MCAP output."""

    compression: str = "zstd"  # none | lz4 | zstd
    chunk_size: int = 1024 * 1024
    split_size_mb: float = 0.0  # 0 = one file
    split_duration_s: float = 0.0
    keys: str = "stereovox/**"
    queue_mb: float = 256.0  # received messages waiting for the disk, at most
    when_full: str = "drop"  # drop (count, never slow the pipeline) | block (push back, lose nothing)
    flush_interval_s: float = 1.0  # a SIGKILL loses at most this much (one chunk)
    stop_quiet_s: float = 1.0  # on a clean stop, keep listening until nothing arrived for this long
    stop_quiet_max_s: float = 5.0  # ... but no longer than this, on a bus that never goes quiet


@dataclass
class ReplayConfig:
    """Camera replay."""

    rate: float = 1.0  # 0 = as fast as possible
    lockstep: bool = False  # frame k+1 only after the tracker reported frame k
    lockstep_timeout_s: float = 10.0
    # what lockstep waits for: the tracker (one frame in flight) or stereo_depth/points (paced by the
    # first stage, later stages pipelined)
    lockstep_topic: str = "tracker/obstacles"
    image_format: str = "raw"  # raw | png | jpeg on the wire, or recorded: as stored, not re-encoded
    topics: list[str] = field(default_factory=lambda: ["camera/stereo", "vehicle/**", "groundtruth/**"])
    wait_for: list[str] = field(default_factory=list)  # services whose liveliness to await first
    wait_timeout_s: float = 60.0


@dataclass
class Config:
    """The whole tree."""

    bus: BusConfig = field(default_factory=BusConfig)
    volume: VolumeConfig = field(default_factory=VolumeConfig)
    stereo: StereoConfig = field(default_factory=StereoConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    voxel: VoxelConfig = field(default_factory=VoxelConfig)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    recorder: RecorderConfig = field(default_factory=RecorderConfig)
    replay: ReplayConfig = field(default_factory=ReplayConfig)
    health_period_s: float = 1.0

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)
