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

import numba
import numpy as np
import numpy.typing as npt

NDArray = npt.NDArray[Any]

#: faces kept per track (0.8 s at 10 Hz; 6 lost a 1.4 m/s pedestrian on urban seed 7, 10 gained nothing).
SIZE: int = 8
#: fewest faces a slope is taken from; below it the window has no opinion (speed bound -inf). A line
#: through three faces leaves one degree of freedom for its scatter, which then says little: with
#: four, tracker replays called 9 fewer false moving frames for 8 fewer true ones held out, 5 for 4
#: on the tuning seeds and 3 for 4 on the fresh ones, and overtake's moving TP 89.8 -> 91.4 %
#: (docs/results/tracking.md, "Session 37"; 3 before).
MIN_POINTS: int = 4


def push(points: NDArray, times: NDArray, count: NDArray, rows: NDArray, new_points: NDArray, now: float) -> None:
    """Append one horizontal position (world x, y) per row in ``rows`` at time ``now``, in place.

    ``points`` is (n, size, 2), ``times`` (n, size) and ``count`` (n,); the newest entry is last
    and the oldest falls out once the window is full.
    """
    if len(rows) == 0:
        return
    push_points(points, rows, new_points)
    times[rows, :-1] = times[rows, 1:]
    times[rows, -1] = now
    count[rows] = np.minimum(count[rows] + 1, points.shape[1])


def push_points(points: NDArray, rows: NDArray, new_points: NDArray) -> None:
    """``push``'s positions alone: for a second window (the far ends) sharing the first's times and counts."""
    if len(rows) == 0:
        return
    _shift_in(points, np.asarray(rows, dtype=np.int64), np.ascontiguousarray(new_points, dtype=np.float64))


@numba.njit(cache=True)
def _shift_in(points: NDArray, rows: NDArray, new_points: NDArray) -> None:
    size = points.shape[1]
    for i in range(rows.shape[0]):
        r = rows[i]
        for s in range(size - 1):
            points[r, s, 0], points[r, s, 1] = points[r, s + 1, 0], points[r, s + 1, 1]
        points[r, size - 1, 0], points[r, size - 1, 1] = new_points[i, 0], new_points[i, 1]


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
    products instead of a second fit. Compiled, track by track: the same fit over numpy's
    batched arrays cost a tenth of the tracker's time with 50 tracks.
    """
    n = count.shape[0]
    along = direction is not None
    d = np.ascontiguousarray(direction, dtype=np.float64) if along else np.zeros((n, 2))
    return _bounds(*_compiled(points, times, count), float(floor_std), float(k), d, along)


def _compiled(points: NDArray, times: NDArray, count: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """A window's arrays as the compiled fits take them (contiguous float64 and int64): one signature each."""
    return (
        np.ascontiguousarray(points, dtype=np.float64),
        np.ascontiguousarray(times, dtype=np.float64),
        np.ascontiguousarray(count, dtype=np.int64),
    )


@numba.njit(cache=True)
def _fit(points: NDArray, times: NDArray, m: int, p_mean: NDArray, slope: NDArray) -> tuple[float, float]:
    """The least-squares line through one track's newest ``m`` faces: their mean position and slope
    into ``p_mean`` and ``slope``; their mean time and the sum of squared time offsets returned."""
    size, axes = points.shape[0], points.shape[1]
    first = size - m
    t_mean = 0.0
    for s in range(first, size):
        t_mean += times[s]
    t_mean /= m
    sxx = 0.0
    for s in range(first, size):
        sxx += (times[s] - t_mean) ** 2
    sxx = max(sxx, 1e-12)
    for a in range(axes):
        p_mean[a] = 0.0
        for s in range(first, size):
            p_mean[a] += points[s, a]
        p_mean[a] /= m
        acc = 0.0
        for s in range(first, size):
            acc += (times[s] - t_mean) * (points[s, a] - p_mean[a])
        slope[a] = acc / sxx
    return t_mean, sxx


@numba.njit(cache=True)
def _bounds(
    points: NDArray, times: NDArray, count: NDArray, floor_std: float, k: float, direction: NDArray, along: bool
) -> tuple[NDArray, NDArray]:
    n, size, axes = points.shape
    whole, along_out = np.full(n, -np.inf), np.full(n, -np.inf)
    slope, p_mean = np.empty(axes), np.empty(axes)
    for i in range(n):
        m = count[i]
        if m < MIN_POINTS:
            continue
        first = size - m  # the newest ``m`` entries
        t_mean, sxx = _fit(points[i], times[i], m, p_mean, slope)
        rss, rss_along, speed, speed_along = 0.0, 0.0, 0.0, 0.0
        for a in range(axes):
            speed += slope[a] ** 2
            speed_along += slope[a] * direction[i, a]
        for s in range(first, size):
            dt = times[i, s] - t_mean
            projected = 0.0
            for a in range(axes):
                residual = points[i, s, a] - p_mean[a] - dt * slope[a]
                rss += residual**2
                projected += residual * direction[i, a]
            rss_along += projected**2
        dof = max(m - 2.0, 0.0)
        # the scatter per axis, never below the floor
        whole[i] = np.sqrt(speed) - k * np.sqrt(max(rss / max(axes * dof, 1.0), floor_std**2) / sxx)
        if along:
            along_out[i] = abs(speed_along) - k * np.sqrt(max(rss_along / max(dof, 1.0), floor_std**2) / sxx)
    return whole, along_out


def line_velocity(
    points: NDArray, times: NDArray, count: NDArray, min_faces: int, floor_std: float
) -> tuple[NDArray, NDArray]:
    """(n, 2) velocity of the least-squares line through each track's faces, and (n,) its standard error.

    The standard error is nan where fewer than ``min_faces`` faces are held; the scatter is pooled
    over both axes and never taken below ``floor_std`` (m), as in ``speed_bounds``. Compiled, track
    by track, as ``speed_bounds`` is: over numpy's batched arrays it cost 4 % of the tracker's time.
    """
    return _line(*_compiled(points, times, count), int(min_faces), float(floor_std))


@numba.njit(cache=True)
def _line(points: NDArray, times: NDArray, count: NDArray, min_faces: int, floor_std: float) -> tuple[NDArray, NDArray]:
    n, size, axes = points.shape
    slope, se = np.zeros((n, axes)), np.full(n, np.nan)
    centre = np.empty(axes)
    for i in range(n):
        m = min(count[i], size)
        if m <= 0:
            continue
        first = size - m  # the newest ``m`` entries
        t_mean, sxx = _fit(points[i], times[i], m, centre, slope[i])
        if count[i] < min_faces:
            continue
        rss = 0.0
        for s in range(first, size):
            dt = times[i, s] - t_mean
            for a in range(axes):
                rss += (points[i, s, a] - centre[a] - dt * slope[i, a]) ** 2
        scatter = max(rss / (axes * max(m - 2.0, 1.0)), floor_std**2)
        se[i] = np.sqrt(scatter / sxx)
    return slope, se
