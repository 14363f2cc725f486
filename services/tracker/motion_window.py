"""A second opinion on a track's speed: a straight line through its last few measured positions.

The Kalman velocity is a running blend of everything the track has seen. When a cluster's faces
slide for a while (a parked car at 35 m whose depth is off by a metre that shrinks as the vehicle
closes in, a hedge uncovered by a parked car it was hidden behind) the filter learns that slide as
a velocity and, with a process noise fit for real vehicles, keeps it for a second or more after the
faces have stopped: on KITTI tracking 0001 tracks of static structures went on reporting 3-6 m/s
for 10-20 frames while the faces they followed stood still in the world. The slope of the last
``size`` faces, with a standard error taken from how far they scatter about that line, forgets
such a slide as soon as it is out of the window, and a set of faces that jump about (a track that
took another object's cluster, a cluster that split) gives a large error rather than a speed.

The moving label (motion_state.py) needs both opinions: a moving object's faces move along a line
however they are blended, so it loses nothing but the frames the window takes to fill.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

NDArray = npt.NDArray[Any]

#: faces kept per track (0.8 s at 10 Hz; 6 lost a 1.4 m/s pedestrian on urban seed 7, 10 gained nothing).
SIZE: int = 8
#: fewest faces a slope is taken from; below it the window has no opinion (speed bound -inf).
MIN_POINTS: int = 3


def push(points: NDArray, times: NDArray, count: NDArray, rows: NDArray, new_points: NDArray, now: float) -> None:
    """Append one horizontal position (world x, y) per row in ``rows`` at time ``now``, in place.

    ``points`` is (n, size, 2), ``times`` (n, size) and ``count`` (n,); the newest entry is last
    and the oldest falls out once the window is full.
    """
    if len(rows) == 0:
        return
    points[rows, :-1] = points[rows, 1:]
    times[rows, :-1] = times[rows, 1:]
    points[rows, -1] = new_points[:, 0:2]
    times[rows, -1] = now
    count[rows] = np.minimum(count[rows] + 1, points.shape[1])


def restart(count: NDArray, rows: NDArray) -> None:
    """Forget every entry of ``rows``: what came before belongs to another cluster shape.

    Called before the new face is pushed, so the window starts again from that face alone.
    Keeping the last old face instead holds a fresh window's bound down (it shows as scatter):
    measured, that calls 4 fewer synthetic parked tracks moving (of 199) but doubles KITTI 0001's
    stationary objects labelled moving (3.2 -> 6.5 %), so the window forgets it
    (docs/results/tracking.md).
    """
    count[rows] = 0


def shift(points: NDArray, rows: NDArray, offset: NDArray) -> None:
    """Move every stored position of ``rows`` by ``offset`` (m, 3): the track now follows another face."""
    points[rows] += offset[:, None, 0:2]


def speed_bounds(
    points: NDArray, times: NDArray, count: NDArray, floor_std: float, k: float, direction: NDArray | None = None
) -> tuple[NDArray, NDArray]:
    """(n,) horizontal speed of the least-squares line minus ``k`` standard errors, -inf when too few;
    then the same along ``direction`` (n, 2 unit vectors; -inf without one).

    The scatter about the line is never taken below ``floor_std`` (m), so three faces that happen
    to line up do not claim a precise speed. Along a direction only the motion and the scatter
    along it count: a bound on the speed all the same. The projection of the fitted line is the
    line fitted to the projected faces, and so are its residuals, so the second bound costs a few
    products instead of a second fit.
    """
    n, size = count.shape[0], points.shape[1]
    whole, along = np.full(n, -np.inf), np.full(n, -np.inf)
    valid = np.arange(size)[None, :] >= (size - count)[:, None]  # the newest ``count`` entries
    ok = count >= MIN_POINTS
    if not ok.any():
        return whole, along
    w = valid[ok].astype(np.float64)
    m = w.sum(axis=1)
    t = times[ok]
    p = points[ok]
    t_mean = (w * t).sum(axis=1) / m
    dt = (t - t_mean[:, None]) * w
    sxx = np.maximum((dt**2).sum(axis=1), 1e-12)
    # einsum: a sum over the middle axis of (k, size, axes) costs three times as much
    p_mean = np.einsum("ks,ksi->ki", w, p) / m[:, None]
    dp = (p - p_mean[:, None, :]) * w[:, :, None]
    slope = np.einsum("ks,ksi->ki", dt, dp) / sxx[:, None]  # (k, axes)
    residual = dp - dt[:, :, None] * slope[:, None, :]  # zero at unused entries, as dp and dt are
    dof = np.maximum(m - 2.0, 0.0)

    def bound(speed: NDArray, rss: NDArray, axes: int) -> NDArray:
        scatter = np.maximum(rss / np.maximum(axes * dof, 1.0), floor_std**2)  # per axis
        return speed - k * np.sqrt(scatter / sxx)

    whole[ok] = bound(np.linalg.norm(slope, axis=1), np.einsum("ksi,ksi->k", residual, residual), points.shape[2])
    if direction is not None:
        d = direction[ok]
        along[ok] = bound(np.abs((slope * d).sum(axis=1)), (np.einsum("nsi,ni->ns", residual, d) ** 2).sum(axis=1), 1)
    return whole, along
