"""Step 1 of the paper: dense disparity by semi-global matching, then coloured 3D points.

``process`` validates the frame, matches it with the two-level SGM of ``matcher.py``, and
reprojects the disparity into the vehicle frame cropped to the volume of interest. The disparity
image is always returned (evaluation and monitors need it), with NaN wherever no honest value
exists. A blank pair (all black, all white) is not an error: it gives an empty cloud and sets
``last_degenerate`` so the bus shell can count it.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TypeVar

import cv2
import numpy as np

from common.config import Config, StereoConfig, VolumeConfig
from common.errors import ConfigError
from common.messages import Calibration, Disparity, PointCloud, StereoFrame
from services.stereo_depth.far_band import far_region
from services.stereo_depth.keypoints import KeypointParams, Keypoints, KeypointTracker
from services.stereo_depth.matcher import MultiResolutionMatcher
from services.stereo_depth.ramps import RampFilter
from services.stereo_depth.reproject import Colors, Points, Reprojector, VolumeCrop
from services.stereo_depth.sgbm import DisparityMap, round_up_16
from services.stereo_depth.validation import check_frame, is_textureless

T = TypeVar("T")

#: matchers kept for different search ranges (one per rig in practice).
MAX_MATCHERS: int = 4
#: pixels of the reach to ``min_depth_m`` that may be given up to save a block of 16 disparities.
REACH_SLACK_PX: float = 1.0


class StereoDepth:
    """Stereo pair in, (PointCloud, Disparity) out; matchers are built once per search range."""

    def __init__(self, stereo: StereoConfig, volume: VolumeConfig) -> None:
        if stereo.min_depth_m <= 0 or stereo.min_points_depth_m <= 0:
            raise ConfigError("stereo.min_depth_m and stereo.min_points_depth_m must be > 0")
        if stereo.num_disparities < 0 or stereo.decimation < 1:
            raise ConfigError("stereo.num_disparities must be >= 0 (0 = from calibration), decimation >= 1")
        if stereo.keypoints < 0 or stereo.keypoint_cell_px < 1:
            raise ConfigError("stereo.keypoints must be >= 0 (0 = off), keypoint_cell_px >= 1")
        if stereo.upsample_beyond_m < 0:  # (with upsample_x 1 nothing is widened, whatever it says)
            raise ConfigError(f"stereo.upsample_beyond_m must be >= 0 (0: all of it), not {stereo.upsample_beyond_m}")
        self.cfg = stereo
        seen = volume.seen()  # and the lookahead beyond it
        self.seen_volume = seen
        self.volume_reach_m = float(np.hypot(seen.x_max, seen.y_half))
        crop = VolumeCrop.from_config(seen, stereo.below_volume_m)
        bias = (stereo.disparity_offset_px, stereo.disparity_edge_px)
        ramps = None
        if stereo.ramp_step_px > 0.0:
            ramps = RampFilter(stereo.ramp_step_px, stereo.ramp_reach_px, stereo.ramp_width_px, stereo.ramp_margin_px,
                               stereo.ramp_flat_share, stereo.ramp_snap_ratio)
        self.reprojector = Reprojector(crop, stereo.min_points_depth_m, stereo.decimation, bias, ramps)
        corners = KeypointParams(max_count=stereo.keypoints, cell_px=stereo.keypoint_cell_px)
        self.keypoint_tracker = KeypointTracker(corners) if stereo.keypoints else None
        self._matchers: dict[tuple[int, ...], MultiResolutionMatcher] = {}
        self.last_degenerate = False
        self.last_timings_ms: dict[str, float] = {}
        self._last_matcher: MultiResolutionMatcher | None = None
        MultiResolutionMatcher.for_range(stereo, round_up_16(stereo.num_disparities or 64))  # fail fast on bad config

    @classmethod
    def from_config(cls, cfg: Config) -> StereoDepth:
        return cls(cfg.stereo, cfg.volume)

    def process(self, frame: StereoFrame) -> tuple[PointCloud, Disparity]:
        check_frame(frame)  # a malformed pair or calibration raises, naming what is wrong
        self.last_timings_ms = {}
        disparity = self._timed("match", lambda: self._disparity(frame))  # SGM at two resolutions, checked
        points, colors = self._timed("reproject", lambda: self.reprojector.points(disparity, frame.left, frame.calib))
        cloud, disp = self._messages(frame, points, colors, disparity)
        tracker = self.keypoint_tracker
        if tracker is not None and not self.last_degenerate:
            keypoints = self._timed("keypoints", lambda: self._keypoints(tracker, frame, disparity))
            std_px = self.cfg.keypoint_disparity_std_px
            cloud.keypoint_ids, cloud.keypoints, cloud.keypoint_std = self.reprojector.keypoints(
                keypoints, frame.calib, std_px
            )
        return cloud, disp

    def _keypoints(self, tracker: KeypointTracker, frame: StereoFrame, disparity: DisparityMap) -> Keypoints:
        left, right = (cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2GRAY) for img in (frame.left, frame.right))
        reach = frame.calib.fx * frame.calib.baseline / self.volume_reach_m  # nothing beyond the volume
        return tracker.update(left, right, disparity, frame.frame_id, reach)

    def step_timings_ms(self) -> dict[str, float]:
        """The last frame's milliseconds per step: the matcher's (``matcher.STEPS``), reproject, keypoints, total."""
        steps = dict(self._last_matcher.timings_ms) if self._last_matcher else {}
        steps["reproject"] = self.last_timings_ms.get("reproject", 0.0)
        steps["keypoints"] = self.last_timings_ms.get("keypoints", 0.0)
        steps["total"] = self.last_timings_ms.get("match", 0.0) + steps["reproject"] + steps["keypoints"]
        return steps

    def _disparity(self, frame: StereoFrame) -> DisparityMap:
        """The left image's disparity; all NaN (and flagged) for a blank pair or one with no match at all."""
        self._last_matcher = None
        if is_textureless(frame.left) or is_textureless(frame.right):
            self.last_degenerate = True
            return np.full(frame.left.shape[:2], np.nan, dtype=np.float32)
        self._last_matcher = self._matcher(frame.calib)
        disparity = self._last_matcher.match(frame.left, frame.right)
        self.last_degenerate = not bool(np.isfinite(disparity).any())
        return disparity

    def search_range(self, calib: Calibration) -> int:
        """Full-resolution disparities to search: down to ``min_depth_m`` unless fixed in config.

        The reach is rounded up to SGBM's multiple of 16 after giving up one pixel of it: KITTI's
        192.2 px would otherwise cost a 208-disparity search (and 112 instead of 96 at half
        resolution) for 0.5 % of depth at 2 m.
        """
        if self.cfg.num_disparities:
            return round_up_16(self.cfg.num_disparities)
        reach = calib.fx * calib.baseline / self.cfg.min_depth_m - REACH_SLACK_PX
        return round_up_16(min(reach, calib.width))

    def _matcher(self, calib: Calibration) -> MultiResolutionMatcher:
        disparities = self.search_range(calib)
        far = None
        if self.cfg.upsample_x > 1 and self.cfg.upsample_beyond_m > 0:
            far = far_region(calib, self.seen_volume, self.cfg.upsample_beyond_m)
        key = (disparities, *(far or ()))
        if key not in self._matchers:
            if len(self._matchers) >= MAX_MATCHERS:  # a stream of ever-new calibrations must not grow memory
                self._matchers.clear()
            self._matchers[key] = MultiResolutionMatcher.for_range(self.cfg, disparities, far)
        return self._matchers[key]

    def _timed(self, stage: str, work: Callable[[], T]) -> T:
        start = time.perf_counter()
        result = work()
        self.last_timings_ms[stage] = (time.perf_counter() - start) * 1000.0
        return result

    @staticmethod
    def _messages(
        frame: StereoFrame, points: Points, colors: Colors, disparity: DisparityMap
    ) -> tuple[PointCloud, Disparity]:
        cloud = PointCloud(
            frame_id=frame.frame_id,
            stamp_ns=frame.stamp_ns,
            points=points,
            colors=colors,
            origin=np.array(frame.calib.cam_to_vehicle, dtype=np.float64)[:3, 3],
        )
        disp = Disparity(frame_id=frame.frame_id, stamp_ns=frame.stamp_ns, disparity=disparity, calib=frame.calib)
        return cloud, disp
