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

from common.geometry import rot_z
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


def yaw_of(step: F64) -> float:
    """Rotation of a vehicle step about the up axis (z), radians."""
    return float(np.arctan2(step[1, 0], step[0, 0]))


def fuse_step(
    step: F64, covariance: F64, vehicle: VehicleMotion, dt: float, noise: SensorNoise
) -> tuple[F64, F64]:
    """A vehicle step (the current vehicle frame in the previous one) corrected by the sensors, and
    its covariance.

    ``covariance`` is the vision's, over (x, y, z, roll, pitch, yaw) of the step. Distance is
    fused along the step's own direction, so a vision step that is well placed but too long is
    shortened without being turned. The published covariance is the vision's with the variance
    along the step and that of yaw replaced by the fused ones.
    """
    out, cov = step.copy(), covariance.copy()
    translation = step[0:3, 3]
    length = float(np.linalg.norm(translation))
    sensor_length = sensor_distance(vehicle, dt)
    length_var_sensor = (noise.speed_mps * dt) ** 2
    if length > 1e-6:
        direction = translation / length
        own_var = float(direction @ covariance[0:3, 0:3] @ direction)
        length_var = own_var + (noise.vision_scale * length) ** 2
        out[0:3, 3] = direction * _mean(length, length_var, sensor_length, length_var_sensor)
        along = np.outer(direction, direction)
        cov[0:3, 0:3] += (_fused_var(length_var, length_var_sensor) - own_var) * along
    yaw = yaw_of(step)
    yaw_var = float(covariance[5, 5]) + (noise.vision_yaw_per_m * length) ** 2
    yaw_var_sensor = (noise.yaw_rate_rps * dt) ** 2
    fused_yaw = _mean(yaw, yaw_var, vehicle.yaw_rate_rps * dt, yaw_var_sensor)
    out[0:3, 0:3] = rot_z(fused_yaw - yaw) @ step[0:3, 0:3]
    cov[5, 5] = _fused_var(yaw_var, yaw_var_sensor)
    return out, cov


def _mean(a: float, var_a: float, b: float, var_b: float) -> float:
    """Inverse-variance mean of two measurements of one quantity."""
    return (a * var_b + b * var_a) / max(var_a + var_b, 1e-18)


def _fused_var(var_a: float, var_b: float) -> float:
    return var_a * var_b / max(var_a + var_b, 1e-18)


def sensor_distance(vehicle: VehicleMotion, dt: float) -> float:
    """Straight-line length of the step: the chord of the arc the vehicle drove."""
    half_turn = 0.5 * vehicle.yaw_rate_rps * dt
    return abs(vehicle.speed_mps) * dt * float(np.sinc(half_turn / np.pi))


def sensor_step(vehicle: VehicleMotion, dt: float) -> F64:
    """The step the sensors alone give: the chord of the arc that speed and yaw rate describe."""
    yaw = vehicle.yaw_rate_rps * dt
    out = np.eye(4)
    out[0:3, 0:3] = rot_z(yaw)
    out[0:3, 3] = np.sign(vehicle.speed_mps) * sensor_distance(vehicle, dt) * np.array(
        [np.cos(0.5 * yaw), np.sin(0.5 * yaw), 0.0]
    )
    return out


def sensor_covariance(vehicle: VehicleMotion, dt: float, noise: SensorNoise) -> F64:
    """Covariance of :func:`sensor_step`: along the step from speed, across it from the yaw's
    uncertainty swinging the chord, yaw from the gyro.

    Height, roll and pitch are not measured; the road plane is an assumption, so they get the
    along-track value and a vague 1 degree.
    """
    along = (noise.speed_mps * dt) ** 2
    yaw_var = (noise.yaw_rate_rps * dt) ** 2
    across = (0.5 * sensor_distance(vehicle, dt)) ** 2 * yaw_var
    vague = np.radians(1.0) ** 2
    return np.diag([along, across, along, vague, vague, yaw_var])
