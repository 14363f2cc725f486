"""The vehicle's own motion sensors fused into the visual step (optional, ``odometry.fuse_ins``).

An INS or wheel speed and a gyro measure the two things stereo odometry measures worst: how far
the vehicle went (a disparity bias of a tenth of a pixel moves the scale by a percent, see
docs/results/odometry.md) and how much it turned. They are also there when vision is not: a
blank or blurred frame is bridged by the sensors instead of by repeating the last motion.

The fusion is per frame and per quantity, distance travelled and yaw, each an inverse-variance
mean of the two measurements; the step's direction and its other rotations stay the vision's.
The paper names this (INS/GPS fusion) as its future work.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.messages import VehicleMotion

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class SensorNoise:
    """One sigma of the sensors (speed m/s, yaw rate rad/s) and of vision beyond its own covariance.

    The vision's covariance comes from its reprojection residuals and says nothing of a disparity
    bias, which scales every step alike (KITTI: +0.04 to +2.8 % before the rig correction, a
    hundred times the covariance's sigma of a 1 m step). ``vision_scale`` (share of the step) and
    ``vision_yaw_per_m`` (rad per metre) are that part, added before the two are weighed.
    """

    speed_mps: float
    yaw_rate_rps: float
    vision_scale: float = 0.0
    vision_yaw_per_m: float = 0.0


def _yaw_rotation(angle: float) -> F64:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def yaw_of(step: F64) -> float:
    """Rotation of a vehicle step about the up axis (z), radians."""
    return float(np.arctan2(step[1, 0], step[0, 0]))


def fuse_step(step: F64, covariance: F64, vehicle: VehicleMotion, dt: float, noise: SensorNoise) -> F64:
    """A vehicle step (the current vehicle frame in the previous one) corrected by the sensors.

    ``covariance`` is the vision's, over (x, y, z, roll, pitch, yaw) of the step. Distance is
    fused along the step's own direction, so a vision step that is well placed but too long is
    shortened without being turned.
    """
    out = step.copy()
    translation = step[0:3, 3]
    length = float(np.linalg.norm(translation))
    sensor_length = abs(vehicle.speed_mps) * dt
    length_var_sensor = (noise.speed_mps * dt) ** 2
    if length > 1e-6:
        direction = translation / length
        length_var = float(direction @ covariance[0:3, 0:3] @ direction) + (noise.vision_scale * length) ** 2
        fused = (length * length_var_sensor + sensor_length * length_var) / max(length_var + length_var_sensor, 1e-18)
        out[0:3, 3] = direction * fused
    yaw = yaw_of(step)
    yaw_var = float(covariance[5, 5]) + (noise.vision_yaw_per_m * length) ** 2
    yaw_var_sensor = (noise.yaw_rate_rps * dt) ** 2
    fused_yaw = (yaw * yaw_var_sensor + vehicle.yaw_rate_rps * dt * yaw_var) / max(yaw_var + yaw_var_sensor, 1e-18)
    out[0:3, 0:3] = _yaw_rotation(fused_yaw - yaw) @ step[0:3, 0:3]
    return out


def sensor_step(vehicle: VehicleMotion, dt: float) -> F64:
    """The step the sensors alone give: along the arc that speed and yaw rate describe, on the road plane."""
    yaw = vehicle.yaw_rate_rps * dt
    distance = vehicle.speed_mps * dt
    out = np.eye(4)
    out[0:3, 0:3] = _yaw_rotation(yaw)
    out[0:3, 3] = distance * np.array([np.cos(0.5 * yaw), np.sin(0.5 * yaw), 0.0])
    return out


def sensor_covariance(dt: float, noise: SensorNoise) -> F64:
    """Covariance of :func:`sensor_step`: along and across the step from speed, yaw from the gyro.

    Roll and pitch are not measured; the road plane is an assumption, so they get a vague 1 degree.
    """
    along = (noise.speed_mps * dt) ** 2
    vague = np.radians(1.0) ** 2
    return np.diag([along, along, along, vague, vague, (noise.yaw_rate_rps * dt) ** 2])
