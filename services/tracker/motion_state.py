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


def speed_and_sigma(velocity: NDArray, velocity_cov: NDArray) -> tuple[NDArray, NDArray]:
    """Horizontal speed (n,) and its standard deviation along the velocity's direction."""
    v = velocity[:, 0:2]
    speed = np.linalg.norm(v, axis=1)
    direction = v / np.maximum(speed, 1e-9)[:, None]
    cov = velocity_cov[:, 0:2, 0:2]
    var = np.einsum("ni,nij,nj->n", direction, cov, direction)
    # at zero speed the direction is arbitrary: take the larger axis variance, the cautious choice
    var = np.where(speed > 1e-9, var, np.maximum(cov[:, 0, 0], cov[:, 1, 1]))
    return speed, np.sqrt(np.maximum(var, 0.0))


def slide_speed(extent: NDArray, extent_slow: NDArray, period_s: float, voxel_edge: float) -> NDArray:
    """Horizontal centroid speed (n,) a steadily growing or shrinking box explains on its own.

    ``extent_slow`` trails ``extent`` by ``lag`` seconds under steady growth, so their difference
    over ``lag`` is the growth rate; half of it is the slide of a box growing on one side. A box
    flickers by a voxel at its faces from quantisation alone, so one voxel edge of difference per
    axis is not counted as growth.
    """
    lag = period_s * (1.0 - SLIDE_SMOOTHING) / SLIDE_SMOOTHING
    growth = np.maximum(np.abs(extent - extent_slow)[:, 0:2] - voxel_edge, 0.0)
    return 0.5 * np.linalg.norm(growth, axis=1) / lag


def label(
    moving: NDArray,
    speed: NDArray,
    sigma: NDArray,
    slide: NDArray,
    age: NDArray,
    rule: Hysteresis,
    confirm: NDArray | None = None,
) -> NDArray:
    """New moving flags from the previous ones.

    ``confirm`` is a second lower bound on the speed (motion_window.py), -inf where it has no
    opinion yet: turning moving needs it above ``on`` as well, and a moving track whose window
    falls below ``off`` turns stationary; without an opinion the filter's bound decides alone.
    """
    bound = speed - rule.sigma_k * sigma - slide
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
