"""Stereo visual odometry (the paper's step 2): features, the four-image circle, RANSAC + LM.

State is the last frame that could anchor a motion estimate (its features, stereo matches and
grey images), the vehicle pose at that frame, and the last per-frame camera motion, which both
predicts where features will reappear and bridges frames on which the estimate fails.

Published covariance: 6x6 over (x, y, z, roll, pitch, yaw) of a right perturbation of ``delta``
in the current vehicle frame (metres, radians), from the final LM Jacobian scaled by the residual
variance; a predicted (invalid) step carries a deliberately vague diagonal instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.config import Config, OdometryConfig
from common.errors import CalibrationError, InputError
from common.geometry import invert
from common.messages import Calibration, EgoMotion, StereoFrame, VehicleMotion
from services.odometry.circular_matching import close_circle, match_stereo, match_temporal
from services.odometry.features import FeatureDetector, Features, strongest_per_cell, to_gray
from services.odometry.ins import SensorNoise, fuse_step, sensor_covariance, sensor_step
from services.odometry.looming import plane_jacobians
from services.odometry.motion import MotionEstimate, Rig, estimate_motion, project, triangulate
from services.odometry.subpixel import refine_circle

F64 = npt.NDArray[np.float64]

#: covariance published with a predicted (invalid) step: metres and radians, deliberately vague.
PREDICTED_COVARIANCE = np.diag([1.0, 1.0, 1.0, 0.1, 0.1, 0.1])


@dataclass(frozen=True)
class StereoView:
    """One frame as the odometry keeps it: grey images, features and their stereo matches."""

    left_gray: npt.NDArray[np.uint8]
    right_gray: npt.NDArray[np.uint8]
    left: Features
    right: Features
    left_to_right: npt.NDArray[np.intp]
    right_to_left: npt.NDArray[np.intp]


def rig_of(calib: Calibration) -> Rig:
    """The projection parameters of a frame, refusing a calibration that cannot triangulate."""
    values = (calib.fx, calib.fy, calib.baseline)
    if not all(np.isfinite(v) and v > 0 for v in values) or not (np.isfinite(calib.cx) and np.isfinite(calib.cy)):
        raise CalibrationError(f"odometry needs positive finite fx, fy, baseline; got {values}")
    return Rig(
        fx=float(calib.fx), fy=float(calib.fy), cx=float(calib.cx), cy=float(calib.cy), baseline=float(calib.baseline)
    )


def camera_to_vehicle_motion(motion: F64, cam_to_vehicle: F64) -> F64:
    """Vehicle delta (current vehicle frame in the previous one) of a camera point motion."""
    return cam_to_vehicle @ invert(motion) @ invert(cam_to_vehicle)


def vehicle_covariance(cov: F64, cam_to_vehicle: F64) -> F64:
    """Covariance of (x, y, z, roll, pitch, yaw) of the vehicle delta from that of camera (w, v).

    The camera twist maps to the vehicle through the adjoint of ``cam_to_vehicle``; the order is
    swapped to translation first.
    """
    rot, pos = cam_to_vehicle[:3, :3], cam_to_vehicle[:3, 3]
    skew = np.array([[0.0, -pos[2], pos[1]], [pos[2], 0.0, -pos[0]], [-pos[1], pos[0], 0.0]])
    adjoint = np.zeros((6, 6))
    adjoint[:3, 3:] = skew @ rot  # translation part from camera w
    adjoint[:3, :3] = rot  # translation part from camera v
    adjoint[3:, 3:] = rot  # rotation part from camera w
    swap = np.zeros((6, 6))
    swap[:3, 3:] = np.eye(3)
    swap[3:, :3] = np.eye(3)
    full = adjoint @ swap  # acts on (w, v) ordered input
    return full @ cov @ full.T


class StereoOdometry:
    """Frame-to-frame stereo odometry with explicit failure, bridging and world re-anchoring."""

    def __init__(self, config: OdometryConfig, initial_epoch: int = 0) -> None:
        self.cfg = config
        self.detector = FeatureDetector(
            config.fast_threshold,
            config.feature_cell_px,
            config.features_per_cell,
            config.max_features,
            config.min_corners,
            config.min_fast_threshold,
        )
        self.rng = np.random.default_rng(config.seed)
        self.epoch = initial_epoch
        self.anchor: StereoView | None = None
        self.anchor_pose = np.eye(4)
        self.gap = 0  # frames between the anchor and the current frame
        self.pose = np.eye(4)
        self.velocity: F64 | None = None  # last per-frame camera motion
        self.lost = 0
        self.noise = SensorNoise(
            config.ins_speed_std_mps,
            np.radians(config.ins_yaw_rate_std_dps),
            config.ins_vision_scale_std,
            np.radians(config.ins_vision_yaw_std_dpm),
        )
        self.sensors: VehicleMotion | None = None  # this frame's INS sample, when fusing
        self.anchor_stamp_ns = 0  # when the anchor was seen
        self.pose_stamp_ns = 0  # when the last published pose was
        self.cam_to_vehicle = np.eye(4)  # this frame's rig on the vehicle: where the road is

    @classmethod
    def from_config(cls, cfg: Config, initial_epoch: int = 0) -> StereoOdometry:
        return cls(cfg.odometry, initial_epoch)

    def process(self, frame: StereoFrame, vehicle: VehicleMotion | None = None) -> EgoMotion:
        """Vehicle pose for one stereo frame, following StereoScan's steps.

        ``vehicle`` is the INS sample of the same frame; it is used only with ``fuse_ins`` on.
        """
        rig = rig_of(frame.calib)
        self.cam_to_vehicle = np.asarray(frame.calib.cam_to_vehicle, dtype=np.float64)
        self.sensors = vehicle if self.cfg.fuse_ins else None
        view = self.observe(frame)
        if self.anchor is not None and self.anchor.left_gray.shape != view.left_gray.shape:
            self.epoch += 1  # another camera (or resolution): nothing relates it to the old world
            self.anchor = None
        if self.anchor is None:
            return self.start_world(frame, view)
        self.gap += 1
        estimate = self.match_and_estimate(self.anchor, view, rig)
        if estimate is None:
            return self.bridge(frame, view)
        return self.advance(frame, view, estimate)

    # ------------------------------------------------------------------ steps

    @staticmethod
    def seconds(later_ns: int, earlier_ns: int) -> float | None:
        """Seconds between two frame stamps; None when they do not increase."""
        return (later_ns - earlier_ns) * 1e-9 if later_ns > earlier_ns else None

    def observe(self, frame: StereoFrame) -> StereoView:
        """Features in both images and their stereo matches (the circle's current leg)."""
        if frame.left.shape != frame.right.shape or frame.left.ndim != 3 or frame.left.dtype != np.uint8:
            raise InputError(
                f"stereo pair must be two HxWx3 uint8 images of one size: {frame.left.shape} {frame.left.dtype}, "
                f"{frame.right.shape} {frame.right.dtype}"
            )
        left_gray, right_gray = to_gray(frame.left), to_gray(frame.right)
        left, right = self.detector.detect_pair(left_gray, right_gray)
        l2r, r2l = match_stereo(left, right, self.cfg.min_disparity, self.cfg.max_disparity, self.cfg.row_tolerance_px)
        return StereoView(left_gray, right_gray, left, right, l2r, r2l)

    def match_and_estimate(self, previous: StereoView, current: StereoView, rig: Rig) -> MotionEstimate | None:
        """Circle matches, sub-pixel refinement, bucketing and RANSAC + LM; None when too few inliers.

        Matching searches a small window around where the expected motion puts each feature. Without
        an expected motion (second frame, after a failure) a coarse estimate from the strongest
        features, searched widely around no motion, provides it.
        """
        prior = self.predicted_motion()
        if prior is not None:
            estimate = self.estimate(previous, current, rig, prior, self.cfg.predicted_radius_px)
            if estimate is not None:
                return estimate
        coarse = self.estimate(self.thinned(previous), self.thinned(current), rig, np.eye(4), self.cfg.match_radius_px)
        if coarse is None:  # a dark or bland frame: too few strong corners, so search with all of them
            return self.estimate(previous, current, rig, np.eye(4), self.cfg.match_radius_px)
        return self.estimate(previous, current, rig, coarse.motion, self.cfg.predicted_radius_px)

    def thinned(self, view: StereoView) -> StereoView:
        """The strongest, well spread features of a view (for the wide coarse search)."""
        cell, count = self.cfg.coarse_cell_px, self.cfg.coarse_features
        left = view.left.subset(strongest_per_cell(view.left.xy, view.left.response, cell, 1, count))
        right = view.right.subset(strongest_per_cell(view.right.xy, view.right.response, cell, 1, count))
        l2r, r2l = match_stereo(left, right, self.cfg.min_disparity, self.cfg.max_disparity, self.cfg.row_tolerance_px)
        return StereoView(view.left_gray, view.right_gray, left, right, l2r, r2l)

    def estimate(
        self, previous: StereoView, current: StereoView, rig: Rig, prior: F64, radius: float
    ) -> MotionEstimate | None:
        quads = self.circle(previous, current, rig, prior, radius)
        if len(quads) < self.cfg.min_inliers:
            return None
        prev_obs, cur_obs = self.refine(previous, current, quads, rig, prior)
        correct_disparity(prev_obs, rig, self.cfg.disparity_offset_px, self.cfg.disparity_edge_px)
        correct_disparity(cur_obs, rig, self.cfg.disparity_offset_px, self.cfg.disparity_edge_px)
        lo, hi = self.cfg.min_disparity, self.cfg.max_disparity
        d_prev, d_cur = prev_obs[:, 0] - prev_obs[:, 2], cur_obs[:, 0] - cur_obs[:, 2]
        usable = (d_prev >= lo) & (d_prev <= hi) & (d_cur >= lo) & (d_cur <= hi)
        # a lens whose rectification is least exact at the sides: keep only the central columns
        reach = self.cfg.usable_width * 0.5 * previous.left_gray.shape[1]
        usable &= (np.abs(prev_obs[:, 0] - rig.cx) <= reach) & (np.abs(cur_obs[:, 0] - rig.cx) <= reach)
        prev_obs, cur_obs = prev_obs[usable], cur_obs[usable]
        if len(prev_obs) < self.cfg.min_inliers:
            return None
        result = estimate_motion(
            prev_obs,
            cur_obs,
            np.ones(len(cur_obs)),
            rig,
            prior,
            self.cfg.ransac_iterations,
            self.cfg.ransac_threshold_px,
            self.rng,
            self.cfg.symmetric,
            self.cfg.robust_px,
        )
        if result is None or int(result.inliers.sum()) < self.cfg.min_inliers:
            return None
        return result

    def circle(
        self, previous: StereoView, current: StereoView, rig: Rig, prior: F64, radius: float
    ) -> npt.NDArray[np.intp]:
        """Circle-closing quadruples (last-left, last-right, previous-right, previous-left)."""
        pred_l = predict(previous.left, previous.right, previous.left_to_right, prior, rig, right_image=False)
        pred_r = predict(previous.right, previous.left, previous.right_to_left, prior, rig, right_image=True)
        lp_to_lc, _ = match_temporal(previous.left, pred_l, current.left, radius)
        _, rc_to_rp = match_temporal(previous.right, pred_r, current.right, radius)
        return close_circle(current.left_to_right, rc_to_rp, previous.right_to_left, lp_to_lc)

    def refine(
        self, previous: StereoView, current: StereoView, quads: npt.NDArray[np.intp], rig: Rig, prior: F64
    ) -> tuple[F64, F64]:
        """Sub-pixel observations of the bucketed circle matches: previous and current, N x 4.

        With ``warp_temporal`` each previous-left window is first mapped as the expected motion
        ``prior`` maps its surface (services/odometry/looming.py).
        """
        keep = strongest_per_cell(
            previous.left.xy[quads[:, 3]],
            previous.left.response[quads[:, 3]],
            self.cfg.bucket_px,
            self.cfg.bucket_matches,
            len(quads),
        )
        q = quads[keep]
        warps = None
        if self.cfg.warp_temporal:
            warps = plane_jacobians(previous.left.xy[q[:, 3]].astype(np.float64),
                                    previous.right.xy[q[:, 2]].astype(np.float64), prior, rig,
                                    self.cam_to_vehicle, self.cfg.warp_ground_m)  # fmt: skip
        prev_obs, cur_obs, ok = refine_circle(
            (previous.left_gray, previous.right_gray, current.left_gray, current.right_gray),
            (
                previous.left.xy[q[:, 3]],
                previous.right.xy[q[:, 2]],
                current.left.xy[q[:, 0]],
                current.right.xy[q[:, 1]],
            ),
            self.cfg.subpixel_window,
            2.0,
            self.cfg.subpixel_stereo,
            warps,
        )
        tol = self.cfg.row_tolerance_px
        ok &= (np.abs(prev_obs[:, 1] - prev_obs[:, 3]) <= tol) & (np.abs(cur_obs[:, 1] - cur_obs[:, 3]) <= tol)
        return prev_obs[ok], cur_obs[ok]

    def predicted_motion(self) -> F64 | None:
        """Camera motion expected from the anchor to now: the last motion, once per frame."""
        if self.velocity is None:
            return None
        return np.linalg.matrix_power(self.velocity, self.gap)

    # ------------------------------------------------------------------ outcomes

    def start_world(self, frame: StereoFrame, view: StereoView) -> EgoMotion:
        """First frame of an epoch: the world is this vehicle frame."""
        self.pose = np.eye(4)
        self.anchor_pose = np.eye(4)
        self.gap = 0
        self.lost = 0
        self.velocity = None
        self.anchor = view if self.usable(view) else None
        self.anchor_stamp_ns = self.pose_stamp_ns = frame.stamp_ns
        return self.message(frame, np.eye(4), 0, 0.0, True, np.zeros((6, 6)))

    def advance(self, frame: StereoFrame, view: StereoView, est: MotionEstimate) -> EgoMotion:
        """A good estimate: pose from the anchor, which this frame now replaces."""
        c = frame.calib.cam_to_vehicle
        step = camera_to_vehicle_motion(est.motion, c)
        cov = vehicle_covariance(est.covariance, c)
        motion = est.motion
        dt = self.seconds(frame.stamp_ns, self.anchor_stamp_ns)
        if self.sensors is not None and self.gap == 1 and dt is not None:  # one frame: the sensors measured it too
            step, cov = fuse_step(step, cov, self.sensors, dt, self.noise)
            motion = invert(c) @ invert(step) @ c
        pose = self.anchor_pose @ step
        delta = invert(self.pose) @ pose
        if self.gap == 1:
            self.velocity = motion
        self.pose, self.anchor_pose, self.anchor, self.gap, self.lost = pose, pose, view, 0, 0
        self.anchor_stamp_ns = self.pose_stamp_ns = frame.stamp_ns
        n = int(est.inliers.sum())
        return self.message(frame, delta, n, n / max(len(est.inliers), 1), True, cov)

    def bridge(self, frame: StereoFrame, view: StereoView) -> EgoMotion:
        """A failed estimate: predict from the last motion, or re-anchor after too many failures."""
        self.lost += 1
        if self.lost > self.cfg.max_lost_frames:
            self.epoch += 1
            self.anchor = None
            self.start_world(frame, view)
            return self.message(frame, np.eye(4), 0, 0.0, False, np.zeros((6, 6)))
        c = frame.calib.cam_to_vehicle
        step = np.eye(4) if self.velocity is None else camera_to_vehicle_motion(self.velocity, c)
        cov = PREDICTED_COVARIANCE.copy()
        dt = self.seconds(frame.stamp_ns, self.pose_stamp_ns)
        if self.sensors is not None and dt is not None:  # the sensors know this step better than the last motion
            step, cov = sensor_step(self.sensors, dt), sensor_covariance(self.sensors, dt, self.noise)
        self.pose = self.pose @ step
        self.pose_stamp_ns = frame.stamp_ns
        if self.usable(view):  # a textured but unmatched frame is a better anchor than an old one
            self.anchor, self.anchor_pose, self.gap = view, self.pose.copy(), 0
            self.anchor_stamp_ns = frame.stamp_ns
        return self.message(frame, step, 0, 0.0, False, cov)

    def usable(self, view: StereoView) -> bool:
        """Whether a frame has enough stereo matches to anchor the next estimate."""
        return int((view.left_to_right >= 0).sum()) >= self.cfg.min_inliers

    def message(self, frame: StereoFrame, delta: F64, inliers: int, ratio: float, valid: bool, cov: F64) -> EgoMotion:
        return EgoMotion(
            frame_id=frame.frame_id,
            stamp_ns=frame.stamp_ns,
            pose=self.pose.copy(),
            delta=delta,
            inliers=inliers,
            inlier_ratio=float(ratio),
            valid=valid,
            covariance=cov,
            world_epoch=self.epoch,
        )


def correct_disparity(obs: F64, rig: Rig, offset_px: float, edge_px: float) -> None:
    """Add a rig's disparity bias, as measured against lidar, to observations (in place).

    The bias is ``offset_px + edge_px * ((u - cx) / fx)^2``: a constant, and a part growing towards
    the image sides, where a rectification is least exact (KITTI raw 0009: 0.06 px in the centre,
    0.6 px at the sides, from SGBM and from these features alike). Uncorrected, disparities that are
    too small put points too far away, and the motion between them comes out too long.
    """
    if offset_px == 0.0 and edge_px == 0.0:
        return
    side = (obs[:, 0] - rig.cx) / rig.fx
    obs[:, 2] -= offset_px + edge_px * side * side


def predict(
    features: Features, other: Features, to_other: npt.NDArray[np.intp], motion: F64, rig: Rig, right_image: bool
) -> F64:
    """Where stereo-matched features should appear in the same camera after ``motion`` (NaN: unknown)."""
    out = np.full((len(features), 2), np.nan)
    has = np.flatnonzero(to_other >= 0)
    if len(has) == 0:
        return out
    own, mate = features.xy[has].astype(np.float64), other.xy[to_other[has]].astype(np.float64)
    left, right = (mate, own) if right_image else (own, mate)
    obs = np.concatenate([left, right], axis=1)
    ok = (obs[:, 0] - obs[:, 2]) > 0
    pts = triangulate(obs[ok], rig)
    moved = pts @ motion[:3, :3].T + motion[:3, 3]
    pix = project(moved[None], rig)[0]
    front = moved[:, 2] > 0.1
    cols = (2, 3) if right_image else (0, 1)
    target = has[ok][front]
    out[target] = pix[front][:, cols]
    return out
