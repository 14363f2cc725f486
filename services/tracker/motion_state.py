"""Moving or stationary from the filtered absolute speed, with hysteresis and its uncertainty.

Speed is horizontal: ground obstacles move on the road, and the vertical velocity of a centroid is
only the noise of what part of the object is visible. The label follows a cautious lower bound of
the speed, ``speed - k * sigma - slide``: a track turns moving once that bound is above ``on``, so
a young track whose velocity is still a guess is not called moving, and turns stationary once it
falls below ``off`` (a noisy track hovering at 0.5 m/s does not stay moving for ever); between
the two it keeps its label. It also needs ``min_frames`` frames of track: the first velocity is
two centroids apart, and a cluster changing shape in between fools any noise model.

A box that keeps growing (a parked car's side coming into view, an occluder moving away) drags
its centroid at up to half the growth rate while the object stands still, steadily, so no noise
model averages it out. That slide speed is measured from the box itself and must be cleared too.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

NDArray = npt.NDArray[Any]


#: weight of the newest box in the slow average that measures steady growth (0.6 s at 10 Hz).
SLIDE_SMOOTHING = 0.15


@dataclass(frozen=True)
class Hysteresis:
    """Thresholds (m/s) and how many standard deviations the speed must clear to turn moving."""

    on: float
    off: float
    sigma_k: float
    min_frames: int
    max_floor_m: float = 0.0  # a track whose cluster's lowest voxel is higher above the road never turns moving; 0: off


def speed_and_sigma(velocity: NDArray, velocity_cov: NDArray) -> tuple[NDArray, NDArray]:
    """Horizontal speed (n,) and its standard deviation along the velocity's direction."""
    vx, vy = velocity[:, 0], velocity[:, 1]
    speed = np.hypot(vx, vy)
    dx, dy = vx / np.maximum(speed, 1e-9), vy / np.maximum(speed, 1e-9)
    cxx, cyy = velocity_cov[:, 0, 0], velocity_cov[:, 1, 1]
    # d^T C d written out: a three-operand einsum costs twice as much for a 2 x 2 form
    var = dx * dx * cxx + dx * dy * (velocity_cov[:, 0, 1] + velocity_cov[:, 1, 0]) + dy * dy * cyy
    # at zero speed the direction is arbitrary: take the larger axis variance, the cautious choice
    var = np.where(speed > 1e-9, var, np.maximum(cxx, cyy))
    return speed, np.sqrt(np.maximum(var, 0.0))


def _slide_lag(period_s: float) -> float:
    """Seconds by which the slow extent trails the newest under steady growth."""
    return period_s * (1.0 - SLIDE_SMOOTHING) / SLIDE_SMOOTHING


def slide_speed(extent: NDArray, extent_slow: NDArray, period_s: float, voxel_edge: float) -> NDArray:
    """Horizontal centroid speed (n,) a steadily growing or shrinking box explains on its own.

    ``extent_slow`` trails ``extent`` by ``lag`` seconds under steady growth, so their difference
    over ``lag`` is the growth rate; half of it is the slide of a box growing on one side. A box
    flickers by a voxel at its faces from quantisation alone, so one voxel edge of difference per
    axis is not counted as growth.
    """
    growth = np.maximum(np.abs(extent - extent_slow)[:, 0:2] - voxel_edge, 0.0)
    return 0.5 * np.linalg.norm(growth, axis=1) / _slide_lag(period_s)


def width_slide(now: NDArray, slow: NDArray, period_s: float, voxel_edge: float) -> NDArray:
    """Centre speed (n,) that a width growing or shrinking from ``slow`` to ``now`` explains on its own."""
    return 0.5 * np.maximum(np.abs(now - slow) - voxel_edge, 0.0) / _slide_lag(period_s)


@dataclass(frozen=True)
class Across:
    """A track's motion across its line of sight: the part stereo measures by bearing, not by range.

    A narrow object's range is the noisy part of its position: disparity smear stretches it into a
    fringe along the line of sight whose depth changes with range, and a walker that merges with a
    neighbour along the ray jumps in range. Its bearing is measured to a few centimetres. A walker
    crossing the road moves across the line of sight, so the speed across it bounds the speed from
    below more sharply than the whole velocity does, whose along-sight part carries the smear.
    """

    normal: NDArray  # (n, 2) horizontal unit vectors across the line of sight
    width: NDArray  # (n,) the box's extent across it (m)
    speed: NDArray  # (n,) the velocity's component across it, in magnitude
    sigma: NDArray  # (n,) that component's standard deviation
    slide: NDArray  # (n,) what a steadily widening or narrowing box explains (as slide_speed, across only)


def across_sight(
    position: NDArray,
    velocity: NDArray,
    velocity_cov: NDArray,
    extent: NDArray,
    extent_slow: NDArray,
    eye: NDArray,
    period_s: float,
    voxel_edge: float,
) -> Across:
    """Horizontal ``position`` (n, 2) and ``velocity`` (n, 2) seen from ``eye`` (2,), all in the world."""
    ray = position - eye
    ray = ray / np.maximum(np.linalg.norm(ray, axis=1), 1e-9)[:, None]
    normal = np.column_stack([-ray[:, 1], ray[:, 0]])

    def width(box: NDArray) -> NDArray:
        return np.abs(box[:, 0] * normal[:, 0]) + np.abs(box[:, 1] * normal[:, 1])

    now, slow = width(extent), width(extent_slow)
    nx, ny = normal[:, 0], normal[:, 1]  # n^T C n written out, as in speed_and_sigma
    var = (
        nx * nx * velocity_cov[:, 0, 0]
        + nx * ny * (velocity_cov[:, 0, 1] + velocity_cov[:, 1, 0])
        + ny * ny * velocity_cov[:, 1, 1]
    )
    return Across(
        normal=normal,
        width=now,
        speed=np.abs((velocity * normal).sum(axis=1)),
        sigma=np.sqrt(np.maximum(var, 0.0)),
        slide=width_slide(now, slow, period_s, voxel_edge),
    )


def label(
    moving: NDArray,
    speed: NDArray,
    sigma: NDArray,
    slide: NDArray,
    age: NDArray,
    rule: Hysteresis,
    confirm: NDArray | None = None,
    sigma_k: NDArray | None = None,
) -> NDArray:
    """New moving flags from the previous ones.

    ``confirm`` is a second lower bound on the speed (motion_window.py), -inf where it has no
    opinion yet: turning moving needs it above ``on`` as well, and a moving track whose window
    falls below ``off`` turns stationary; without an opinion the filter's bound decides alone.
    ``sigma_k`` (n,) replaces the rule's ``sigma_k`` track by track.
    """
    bound = speed - (rule.sigma_k if sigma_k is None else sigma_k) * sigma - slide
    turn_on = (bound > rule.on) & (age >= rule.min_frames)
    stay = bound >= rule.off
    if confirm is not None:
        turn_on &= confirm > rule.on
        stay &= np.isneginf(confirm) | (confirm >= rule.off)
    return np.where(moving, stay, turn_on)


class EgoVelocity:
    """The vehicle's world velocity from consecutive valid poses of one world epoch.

    An invalid pose (odometry lost) or a new epoch gives no difference to take; the last velocity
    is kept meanwhile, the best guess for a vehicle that does not stop in 0.1 s.
    """

    def __init__(self) -> None:
        self.velocity: NDArray = np.zeros(3)
        self._position: NDArray | None = None
        self._stamp_ns = 0
        self._epoch = -1

    def observe(self, pose: NDArray, valid: bool, epoch: int, stamp_ns: int) -> None:
        if not valid or not np.isfinite(pose).all():
            return
        position = np.asarray(pose[0:3, 3], dtype=np.float64)
        if epoch == self._epoch and self._position is not None and stamp_ns > self._stamp_ns:
            self.velocity = (position - self._position) / ((stamp_ns - self._stamp_ns) * 1e-9)
        self._position, self._stamp_ns, self._epoch = position, stamp_ns, epoch
