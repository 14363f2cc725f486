"""What a synthetic scene is made of: materials, boxes, objects on known paths, and the ego.

Objects are unions of boxes in their own frame (x along their heading, z up from the surface
they stand on); the ground-truth box is the object's whole extent. Paths are given in road
coordinates with a motion interval, so an object either moves at a constant, clearly non-zero
speed or stands exactly still, and its true velocity is exact; only a walker setting off or
stopping passes through the speeds in between, at a walker's rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from common.geometry import make_pose, rot_y, rot_z
from common.scenarios.road import Road

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Material:
    """A surface's dominant colour (RGB 0..1) and how strongly and finely it is textured."""

    rgb: tuple[float, float, float]
    amp: float = 0.25
    texel: float = 0.02
    phase: float = 0.0


@dataclass(frozen=True)
class Part:
    """One box of an object: centre and full size in the object's frame, and its material."""

    center: tuple[float, float, float]
    size: tuple[float, float, float]
    material: Material


@dataclass(frozen=True)
class Path:
    """Road-coordinate motion at (vs, vd) m/s during [t_start, t_end], standing still outside it.

    With a finite ``accel`` (m/s^2) the object gathers speed from ``t_start`` and comes to a stop
    at ``t_end`` at that rate, as a walker setting off from the kerb does; otherwise it changes
    speed in an instant.
    """

    s0: float
    d0: float
    vs: float = 0.0
    vd: float = 0.0
    t_start: float = -math.inf  # (s0, d0) is where it is at max(t_start, 0)
    t_end: float = math.inf
    yaw: float = 0.0  # heading relative to the road's
    accel: float = math.inf

    def road_at(self, t: float) -> tuple[float, float]:
        m = self._full_speed_s(min(max(t, self.t_start), self.t_end)) - self._full_speed_s(max(self.t_start, 0.0))
        return self.s0 + self.vs * m, self.d0 + self.vd * m

    def _full_speed_s(self, t: float) -> float:
        """Distance travelled by ``t`` (within the motion interval), in seconds at full speed."""
        speed = math.hypot(self.vs, self.vd)
        if math.isinf(self.accel) or speed == 0.0:
            return t
        ramp = speed / self.accel  # seconds to full speed
        if math.isinf(self.t_start):
            end = self.t_end - ramp
            return t - (0.5 * (t - end) ** 2 / ramp if t > end else 0.0)
        u, span = t - self.t_start, self.t_end - self.t_start
        ramp = min(ramp, 0.5 * span)  # a short walk never reaches full speed
        rate = self.accel / speed  # of the full speed, per second
        if u <= ramp:
            return 0.5 * rate * u * u
        up = 0.5 * rate * ramp * ramp
        if u <= span - ramp:
            return up + rate * ramp * (u - ramp)
        left = span - u
        return 2.0 * up + rate * ramp * (span - 2.0 * ramp) - 0.5 * rate * left * left

    def moving_at(self, t: float) -> bool:
        return (self.vs != 0.0 or self.vd != 0.0) and self.t_start < t < self.t_end


@dataclass(frozen=True)
class Thing:
    """A ground-truth object: class, the boxes it is made of, its extent and its path."""

    id: int
    cls: str
    parts: tuple[Part, ...]
    size: tuple[float, float, float]  # length (along heading), width, height
    path: Path


@dataclass(frozen=True)
class ThingState:
    """An object at one instant, in the world frame."""

    thing: Thing
    pose: F64  # object frame (base centre on its surface) -> world
    velocity: F64
    moving: bool

    @property
    def center(self) -> F64:
        return self.pose[:3, 3] + np.array([0.0, 0.0, self.thing.size[2] / 2])

    @property
    def yaw(self) -> float:
        return float(math.atan2(self.pose[1, 0], self.pose[0, 0]))


@dataclass(frozen=True)
class EgoProfile:
    """Ego speed over time (piecewise linear knots) in lane ``d``; starts at s = 0 at t = 0."""

    times: tuple[float, ...]
    speeds: tuple[float, ...]
    d: float

    def s_at(self, t: float) -> float:
        """Distance driven by time ``t``: the exact integral of the piecewise-linear speed."""
        knots = [0.0, *(k for k in self.times if 0.0 < k < t), t]
        v = np.interp(knots, self.times, self.speeds)
        return float(np.sum(np.diff(knots) * (v[1:] + v[:-1]) / 2))


@dataclass(frozen=True)
class Look:
    """How the cameras see the scene: sensor noise, left/right exposure, blur, contrast."""

    noise_sigma: float = 1.5  # grey levels
    exposure_ratio: float = 1.03  # right gain / left gain
    blur_sigma: float = 0.6  # pixels
    brightness: float = 1.0
    contrast: float = 1.0  # scales every texture amplitude


@dataclass(frozen=True)
class World:
    """A whole scenario: road, objects, ego motion and camera look."""

    name: str
    road: Road
    things: tuple[Thing, ...]
    ego: EgoProfile
    look: Look = field(default_factory=Look)

    def ego_pose(self, t: float) -> F64:
        """Vehicle pose in the world; on a grade it pitches with the road over its wheelbase."""
        s = self.ego.s_at(t)
        x, y, heading = (float(a[0]) for a in self.road.to_world(np.array([s]), np.array([self.ego.d])))
        axle = 1.4
        front, rear = self.road.height(np.array([x + axle, x - axle]))
        pitch = math.atan2(float(front - rear), 2 * axle)
        z = float(front + rear) / 2
        return make_pose(rot_z(heading) @ rot_y(-pitch), [x, y, z])

    def ego_velocity(self, t: float, eps: float = 1e-3) -> F64:
        return (self.ego_pose(t + eps)[:3, 3] - self.ego_pose(t - eps)[:3, 3]) / (2 * eps)

    def _base(self, thing: Thing, t: float) -> F64:
        s, d = thing.path.road_at(t)
        x, y, heading = self.road.to_world(np.array([s]), np.array([d]))
        z = self.road.ground_z(x, np.array([d]))
        return np.array([x[0], y[0], z[0], heading[0] + thing.path.yaw])

    def state(self, thing: Thing, t: float, eps: float = 1e-3) -> ThingState:
        """Pose, exact velocity and moving flag of one object at time ``t``."""
        x, y, z, yaw = self._base(thing, t)
        pose = make_pose(rot_z(yaw), [x, y, z])
        moving = thing.path.moving_at(t)
        velocity = np.zeros(3)
        if moving:
            ahead, behind = self._base(thing, t + eps), self._base(thing, t - eps)
            velocity[:2] = (ahead[:2] - behind[:2]) / (2 * eps)
            # the road's grade, not the kerb step a pedestrian climbs
            rise = self.road.height(np.array([ahead[0], behind[0]]))
            velocity[2] = float(rise[0] - rise[1]) / (2 * eps)
        return ThingState(thing, pose, velocity, moving)

    def states(self, t: float) -> list[ThingState]:
        return [self.state(thing, t) for thing in self.things]
