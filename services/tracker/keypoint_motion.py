"""A track's velocity from the corners on it that the stereo stage follows (stereo_depth/keypoints.py).

The filter and the faces' window measure a cluster, and a cluster is whatever the mapper joined
this frame: a walker passing a bin shares one with it, a smear's fringe grows and shrinks with
range. A corner followed in the image stays on the surface it was found on. Each corner's world
positions over its last frames give it a velocity (a line through them); a track's is the median
of its corners' velocities, so corners on a neighbour merged into its cluster are outvoted until
they are half of them. Its doubt is what the stereo stage says of each corner's range (its
disparity's doubt grows with the square of the range) carried through the line's fit, and shrunk
by their number only as far as their errors are their own: corners on one object share part of
them (``SHARED``). Their scatter about the median, where larger, is taken instead.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from common.messages import Cluster
from common.voxel_keys import pack_cells
from services.tracker.track import TrackTable

NDArray = npt.NDArray[Any]

#: world positions kept per corner: 0.8 s at 10 Hz, the faces' window's span.
HISTORY: int = 8
#: frames a corner may go without a disparity before its history is forgotten.
MAX_GAP: int = 2
#: the share of a corner's range error the other corners on the same object have too.
SHARED: float = 0.25
#: scale of the median absolute deviation to a normal distribution's sigma.
MAD_SIGMA: float = 1.4826


@dataclass(frozen=True)
class CornerRule:
    """When the corners on a track label it (config ``tracker.corner_*``; labelling.py)."""

    samples: int = 0  # frames a corner must have been followed for its velocity; 0: corners unused
    min_count: int = 0  # corners a track needs for their opinion
    on_mps: float = 0.0  # the speed they must be sure of to turn it moving
    sigma_k: float = 0.0  # ... sure by this many of their sigmas


NO_CORNERS = CornerRule()


@dataclass(frozen=True)
class CornerVelocity:
    """Per track: the median velocity (n, 2) of the corners on it, its doubt (n,) and their number (n,)."""

    velocity: NDArray
    sigma: NDArray
    count: NDArray


class CornerHistory:
    """Each followed corner's last ``HISTORY`` world positions (x, y) and times, by id.

    The stereo stage drops a corner from a frame whose disparity it could not match (a fifth of a
    walker's corners a frame on synthetic urban) while it goes on following it in the image; such a
    corner keeps its history for ``MAX_GAP`` frames, since its id can only come back on the same
    surface.
    """

    def __init__(self) -> None:
        self.epoch = -1
        self._reset()

    def _reset(self) -> None:
        self.ids = np.zeros(0, dtype=np.int64)
        self.xy = np.zeros((0, HISTORY, 2))
        self.t = np.zeros((0, HISTORY))
        self.n = np.zeros(0, dtype=np.int64)
        self.missed = np.zeros(0, dtype=np.int64)  # frames since last seen; 0: seen this frame
        self.now = np.zeros((0, 3))  # world position where seen this frame
        self.std = np.zeros(0)  # its range's doubt (m, one sigma), as last seen

    def update(self, ids: NDArray, xyz: NDArray, std: NDArray, clock: float, epoch: int) -> None:
        """This frame's corners; one unseen for over ``MAX_GAP`` frames is forgotten, a new world forgets all."""
        if epoch != self.epoch:
            self._reset()
            self.epoch = epoch
        ids = np.asarray(ids, dtype=np.int64)
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        std = np.asarray(std, dtype=np.float64)
        if len(ids) > 1 and not (ids[1:] > ids[:-1]).all():  # the stereo stage sends them in order
            order = np.unique(ids, return_index=True)[1]
            ids, xyz, std = ids[order], xyz[order], std[order]
        state = _merge(self.ids, self.xy, self.t, self.n, self.missed, self.std, ids, xyz, std, clock, MAX_GAP)
        self.ids, self.xy, self.t, self.n, self.missed, self.now, self.std = state

    def ready(self, min_samples: int) -> NDArray:
        """Which corners were seen this frame with ``min_samples`` positions or more."""
        return (self.n >= max(min_samples, 2)) & (self.missed == 0)

    def velocities(self, rows: NDArray) -> tuple[NDArray, NDArray]:
        """The velocities (m, 2) of the lines through these corners' positions, and the doubt (m,) their
        range's brings to them."""
        rows = np.asarray(rows, dtype=np.int64)
        slope, spread = _fit_lines(self.xy, self.t, self.n, rows)
        return slope, self.std[rows] * spread


@numba.njit(cache=True)
def _merge(
    ids: NDArray, xy: NDArray, t: NDArray, n: NDArray, missed: NDArray, std: NDArray,
    new_ids: NDArray, new_xyz: NDArray, new_std: NDArray, clock: float, max_gap: int,
) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray, NDArray, NDArray]:  # fmt: skip
    """The histories after this frame, both id lists sorted: a seen corner's shifted by one slot with
    its new position last, an unseen one's kept as it was for ``max_gap`` frames. Compiled: the same
    with numpy's set operations took 0.3 ms a frame for 1,800 corners."""
    size = ids.shape[0] + new_ids.shape[0]
    o_ids, o_xy, o_t = np.empty(size, np.int64), np.zeros((size, HISTORY, 2)), np.zeros((size, HISTORY))
    o_n, o_missed, o_std = np.ones(size, np.int64), np.zeros(size, np.int64), np.zeros(size)
    o_now = np.full((size, 3), np.nan)
    i = j = k = 0
    while i < ids.shape[0] or j < new_ids.shape[0]:
        if j < new_ids.shape[0] and (i >= ids.shape[0] or new_ids[j] <= ids[i]):
            if i < ids.shape[0] and new_ids[j] == ids[i]:  # seen again: shift its history by one
                o_xy[k, : HISTORY - 1] = xy[i, 1:]
                o_t[k, : HISTORY - 1] = t[i, 1:]
                o_n[k] = min(n[i] + 1, HISTORY)
                i += 1
            o_ids[k] = new_ids[j]
            o_xy[k, HISTORY - 1, 0], o_xy[k, HISTORY - 1, 1] = new_xyz[j, 0], new_xyz[j, 1]
            o_t[k, HISTORY - 1], o_now[k], o_std[k] = clock, new_xyz[j], new_std[j]
            j += 1
            k += 1
        else:  # not seen this frame
            if missed[i] < max_gap:
                o_ids[k], o_xy[k], o_t[k], o_n[k] = ids[i], xy[i], t[i], n[i]
                o_missed[k], o_std[k] = missed[i] + 1, std[i]
                k += 1
            i += 1
    return o_ids[:k], o_xy[:k], o_t[:k], o_n[:k], o_missed[:k], o_now[:k], o_std[:k]


@numba.njit(cache=True)
def _fit_lines(xy: NDArray, t: NDArray, n: NDArray, rows: NDArray) -> tuple[NDArray, NDArray]:
    """Least-squares slopes of x and y against time over each row's last ``n`` slots, and the factor
    1 / sqrt(sum (t - mean t)^2) that turns a position's doubt into the slope's. Compiled: the same in
    numpy over every corner took a millisecond a frame."""
    slope, factor = np.zeros((rows.shape[0], 2)), np.zeros(rows.shape[0])
    for i in range(rows.shape[0]):
        r = rows[i]
        first = HISTORY - n[r]
        t_mean = x_mean = y_mean = 0.0
        for k in range(first, HISTORY):
            t_mean += t[r, k]
            x_mean += xy[r, k, 0]
            y_mean += xy[r, k, 1]
        t_mean, x_mean, y_mean = t_mean / n[r], x_mean / n[r], y_mean / n[r]
        tt = tx = ty = 0.0
        for k in range(first, HISTORY):
            d = t[r, k] - t_mean
            tt += d * d
            tx += d * (xy[r, k, 0] - x_mean)
            ty += d * (xy[r, k, 1] - y_mean)
        tt = max(tt, 1e-12)
        slope[i, 0], slope[i, 1], factor[i] = tx / tt, ty / tt, 1.0 / np.sqrt(tt)
    return slope, factor


def corner_velocity(history: CornerHistory, pieces: list[Cluster], edge: float, min_samples: int) -> CornerVelocity:
    """Each piece's corners (those in its voxels this frame) and their median velocity."""
    n = len(pieces)
    ready = np.flatnonzero(history.ready(min_samples))
    voxels = [np.asarray(p.voxels).reshape(-1, 3) for p in pieces]
    if n == 0 or len(ready) == 0 or sum(len(v) for v in voxels) == 0:
        return CornerVelocity(np.zeros((n, 2)), np.full(n, np.inf), np.zeros(n, dtype=np.int64))
    owner = np.repeat(np.arange(n), [len(v) for v in voxels])
    keys = pack_cells(np.concatenate(voxels))
    order = np.argsort(keys, kind="stable")  # numpy's radix sort: five times a compiled quicksort's speed
    corner_keys = pack_cells(np.floor(history.now[ready] / edge))
    velocity, spread, stereo, count = _piece_velocities(
        keys[order], owner[order], corner_keys, ready, history.xy, history.t, history.n, history.std, n
    )
    m = np.maximum(count, 1).astype(np.float64)
    sigma = np.maximum(MAD_SIGMA * spread / np.sqrt(m), stereo * np.sqrt(SHARED + (1.0 - SHARED) / m))
    return CornerVelocity(velocity, np.where(count > 0, sigma, np.inf), count)


@numba.njit(cache=True)
def _piece_velocities(
    keys: NDArray, owner: NDArray, corner_keys: NDArray, rows: NDArray,
    xy: NDArray, t: NDArray, n: NDArray, std: NDArray, pieces: int,
) -> tuple[NDArray, NDArray, NDArray, NDArray]:  # fmt: skip
    """Per piece, from the corners (``rows``) whose voxel key is one of its (``keys`` sorted, ``owner``
    says whose): the median of their lines' velocities (x, y), the median distance from it, the median
    doubt their ranges bring, and how many. Compiled: numpy took 0.4 ms a frame in some thirty calls."""
    whose = np.full(corner_keys.shape[0], -1, np.int64)
    count = np.zeros(pieces, np.int64)
    for c in range(corner_keys.shape[0]):
        at = np.searchsorted(keys, corner_keys[c])
        if at < keys.shape[0] and keys[at] == corner_keys[c]:
            whose[c] = owner[at]
            count[owner[at]] += 1
    start = np.zeros(pieces + 1, np.int64)
    start[1:] = np.cumsum(count)
    fill, members = start[:-1].copy(), np.empty(start[-1], np.int64)
    for c in range(corner_keys.shape[0]):
        if whose[c] >= 0:
            members[fill[whose[c]]] = rows[c]
            fill[whose[c]] += 1
    velocity, spread, stereo = np.zeros((pieces, 2)), np.zeros(pieces), np.zeros(pieces)
    for p in range(pieces):
        if count[p] == 0:
            continue
        mine = members[start[p] : start[p + 1]]
        slope, factor = _fit_lines(xy, t, n, mine)
        vx, vy = np.median(slope[:, 0]), np.median(slope[:, 1])
        velocity[p, 0], velocity[p, 1] = vx, vy
        spread[p] = np.median(np.sqrt((slope[:, 0] - vx) ** 2 + (slope[:, 1] - vy) ** 2))
        stereo[p] = np.median(std[mine] * factor)
    return velocity, spread, stereo, count


def blend_corners(t: TrackTable, rule: CornerRule, velocity: NDArray, velocity_cov: NDArray) -> None:
    """A moving track's reported horizontal velocity blended with its corners', each by the inverse of
    its variance, where at least ``rule.min_count`` corners are on it; ``velocity_cov`` shrinks alike.

    The corners turn walkers moving whose filter still doubts their speed (labelling.py); what it
    reports for them is that doubted speed, unless the corners' is blended in.
    """
    held = t.moving & (t.corner_count >= max(rule.min_count, 1)) & np.isfinite(t.corner_sigma)
    if rule.samples <= 0 or not held.any():
        return
    reported_var = np.maximum(0.5 * (velocity_cov[:, 0, 0] + velocity_cov[:, 1, 1]), 1e-12)
    sigma = np.where(held, t.corner_sigma, 1.0)
    w = np.where(held, reported_var / (reported_var + sigma * sigma), 0.0)  # the corners' weight
    velocity[:, 0:2] += w[:, None] * (t.corner_velocity - velocity[:, 0:2])
    velocity_cov[:, 0:2, 0:2] *= (1.0 - w)[:, None, None]
