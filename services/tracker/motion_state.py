"""Moving or stationary from the filtered absolute speed, with hysteresis and its uncertainty.

Speed is horizontal: ground obstacles move on the road, and the vertical velocity of a centroid is
only the noise of what part of the object is visible. A track turns moving only once its speed is
above ``on`` by ``k`` standard deviations, so a young track whose velocity is still a guess, or a
parked car whose centroid is sliding, is not called moving; it turns stationary once its speed
falls below ``off``. Between the two it keeps its label.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

NDArray = npt.NDArray[Any]


@dataclass(frozen=True)
class Hysteresis:
    """Thresholds (m/s) and how many standard deviations the speed must clear to turn moving."""

    on: float
    off: float
    sigma_k: float


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


def label(moving: NDArray, speed: NDArray, sigma: NDArray, rule: Hysteresis) -> NDArray:
    """New moving flags from the previous ones."""
    turn_on = speed - rule.sigma_k * sigma > rule.on
    turn_off = speed < rule.off
    return np.where(moving, ~turn_off, turn_on)


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
