"""Disparity to coloured 3D points in the vehicle frame, cropped to the volume of interest.

Each pixel's depth comes from the frame's own calibration (Z = fx * baseline / d), so any rig
and image size works. A pixel's vehicle position is ``Z * ray + t``, with ``ray`` its viewing
direction rotated into the vehicle frame (scaled to unit camera depth): the rays are computed
once per calibration, so the crop can be tested on whole images before any point is gathered.
The crop keeps x and |y| inside the volume but z from ``z_min - below``: the voxel mapper
estimates the road surface itself and needs the road's points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.config import VolumeConfig
from common.geometry import transform
from common.messages import Calibration
from services.stereo_depth.keypoints import Keypoints
from services.stereo_depth.ramps import RampFilter
from services.stereo_depth.sgbm import DisparityMap

Points = npt.NDArray[np.float32]
Colors = npt.NDArray[np.uint8]
Rays = npt.NDArray[np.float32]


@dataclass(frozen=True)
class VolumeCrop:
    """The volume of interest with the road kept: x and |y| as configured, z from z_min - below."""

    x_min: float
    x_max: float
    y_half: float
    z_min: float
    z_max: float

    @classmethod
    def from_config(cls, volume: VolumeConfig, below_m: float) -> VolumeCrop:
        return cls(volume.x_min, volume.x_max, volume.y_half, volume.z_min - below_m, volume.z_max)


def _calib_key(calib: Calibration, step: int) -> tuple[float, ...]:
    pose = tuple(float(v) for v in np.asarray(calib.cam_to_vehicle).ravel())
    return (calib.fx, calib.fy, calib.cx, calib.cy, float(calib.width), float(calib.height), float(step), *pose)


class Reprojector:
    """Keeps the per-pixel rays of the last calibration seen (a rig rarely changes mid-run)."""

    def __init__(
        self,
        crop: VolumeCrop,
        min_depth_m: float,
        decimation: int = 1,
        bias: tuple[float, float] = (0.0, 0.0),
        ramps: RampFilter | None = None,
    ) -> None:
        self.crop = crop
        self.min_depth_m = min_depth_m
        self.step = max(1, int(decimation))
        self.bias_px = bias  # (offset, edge): see ``_corrected``
        self.ramps = ramps  # pixels between two surfaces left out (services/stereo_depth/ramps.py)
        self._key: tuple[float, ...] | None = None
        self._rays: Rays = np.zeros((3, 0, 0), np.float32)

    def points(
        self, disparity: DisparityMap, image: npt.NDArray[np.uint8], calib: Calibration
    ) -> tuple[Points, Colors]:
        """Points (vehicle frame, float32) and RGB colours of every ``decimation``-th pixel in the volume; ramp
        pixels between two surfaces left out or moved onto one (ramps.py)."""
        step = self.step
        if self.ramps is not None:
            disparity = self.ramps.apply(disparity, image)
        disp = disparity[::step, ::step]
        depth = self._depth(disp, calib)
        rays = self._rays_for(calib, disp.shape)
        t = np.asarray(calib.cam_to_vehicle, dtype=np.float64)[:3, 3].astype(np.float32)
        x = depth * rays[0] + t[0]
        y = depth * rays[1] + t[1]
        z = depth * rays[2] + t[2]
        c = self.crop
        keep = (x >= c.x_min) & (x <= c.x_max) & (np.abs(y) <= c.y_half) & (z >= c.z_min) & (z <= c.z_max)
        points = np.stack([x[keep], y[keep], z[keep]], axis=1)  # boolean masks: far cheaper than index pairs
        colors = image[::step, ::step][keep]
        return points, np.ascontiguousarray(colors, dtype=np.uint8)

    def _depth(self, disp: DisparityMap, calib: Calibration) -> npt.NDArray[np.float32]:
        """Depth along the optical axis; NaN for invalid, non-positive or too-near disparities."""
        focal_baseline = np.float32(calib.fx * calib.baseline)
        disp = self._corrected(disp, calib)
        usable = disp <= focal_baseline / np.float32(self.min_depth_m)  # NaN compares False
        usable &= disp > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(usable, focal_baseline / disp, np.float32(np.nan)).astype(np.float32, copy=False)

    def _corrected(self, disp: DisparityMap, calib: Calibration) -> DisparityMap:
        """The disparity plus the rig's bias against lidar, ``offset + edge * ((u - cx) / fx)^2``.

        KITTI's matched disparities are 0.06 px too small in the image centre and 0.6 px at the
        sides (docs/results/odometry.md): uncorrected, a car 30 m ahead comes out ~0.3 m too far,
        and 1-2 m too far at the sides. The published disparity image stays the matcher's own;
        only depths use the correction, exactly as odometry does for its features.
        """
        if self.bias_px == (0.0, 0.0):
            return disp
        return disp + self._bias(np.arange(disp.shape[1], dtype=np.float32) * self.step, calib)[None, :]

    def _bias(self, u: npt.NDArray[np.float32], calib: Calibration) -> npt.NDArray[np.float32]:
        offset, edge = self.bias_px
        side = (u - np.float32(calib.cx)) / np.float32(calib.fx)
        return np.float32(offset) + np.float32(edge) * side * side

    def keypoints(
        self, keypoints: Keypoints, calib: Calibration, disparity_std_px: float
    ) -> tuple[npt.NDArray[np.int64], Points, npt.NDArray[np.float32]]:
        """Followed corners in the vehicle frame (float32) as near as the cloud's points, their ids, and how
        sure their range is: ``disparity_std_px`` of disparity is ``Z / d`` times as many metres."""
        disp = keypoints.disparity + self._bias(keypoints.uv[:, 0], calib)
        near = disp <= np.float32(calib.fx * calib.baseline / self.min_depth_m)
        ids, uv, disp = keypoints.ids[near], keypoints.uv[near], disp[near].astype(np.float64)
        z = calib.fx * calib.baseline / disp
        camera = np.stack([(uv[:, 0] - calib.cx) * z / calib.fx, (uv[:, 1] - calib.cy) * z / calib.fy, z], axis=1)
        points = transform(np.asarray(calib.cam_to_vehicle, dtype=np.float64), camera).astype(np.float32)
        return ids, points, (disparity_std_px * z / disp).astype(np.float32)

    def _rays_for(self, calib: Calibration, shape: tuple[int, ...]) -> Rays:
        key = _calib_key(calib, self.step)
        if key != self._key or self._rays.shape[1:] != shape:
            rows, cols = shape
            u = np.arange(cols, dtype=np.float64) * self.step
            v = np.arange(rows, dtype=np.float64) * self.step
            cam_x = np.broadcast_to(((u - calib.cx) / calib.fx)[None, :], shape)
            cam_y = np.broadcast_to(((v - calib.cy) / calib.fy)[:, None], shape)
            camera = np.stack([cam_x, cam_y, np.ones(shape)])
            rotation = np.asarray(calib.cam_to_vehicle, dtype=np.float64)[:3, :3]
            self._rays = np.einsum("ij,jhw->ihw", rotation, camera).astype(np.float32)
            self._key = key
        return self._rays
