"""Where the corners the stereo stage follows go: each one's world positions over its last frames,
and the median velocity of the corners on a piece of the world (a track's cluster, a part of one).

A corner followed in the image stays on the surface it was found on, so a line through its world
positions is that surface's velocity, whatever the voxels around it were joined into. Where it
does not (at an occluding edge the image tracker can carry it onto the surface behind), its new
position steps off that line, and its history starts again there (``OFF_LINE_SIGMAS``). The median
over a piece's corners outvotes a neighbour's until they are half of them. Its doubt is what the
stereo stage says of each corner's range (its disparity's doubt grows with the square of the
range) carried through the line's fit, and shrunk by their number only as far as their errors are
their own: corners on one object share part of them (``SHARED``). Their scatter about the median,
where larger, is taken instead. Across the line of sight a corner's place is known to a fraction
of a pixel, millimetres at 20 m, so each piece also gets the median of its corners' speeds across
it, with a doubt of its own.

The tracker reads a track's corners here (services/tracker/keypoint_motion.py); the voxel mapper
keeps a standing part and a moving one apart by them (services/voxel_mapper/apart.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from common.corner_lead import NO_LEAD, CornerLead, carry
from common.corner_owners import GRID_CELLS, owners
from common.fast_median import MAD_SIGMA, median

NDArray = npt.NDArray[Any]

#: world positions kept per corner: 0.8 s at 10 Hz, the faces' window's span.
HISTORY: int = 8
#: a row's line as ``_line`` gives it: mean time, mean x and y, slopes of x and y, sum (t - mean t)^2.
FIT: int = 6
#: frames a corner may go without a disparity before its history is forgotten.
MAX_GAP: int = 2
#: the share of a corner's range error the other corners on the same object have too.
SHARED: float = 0.25
#: a corner whose new position lies further off the line through its last three or more than this
#: many of its range's sigmas slid onto another surface: its history starts again there (0: never).
#: KLT follows a walker's edge onto the walker two metres behind him as they pass, and the line
#: through both read 5 m/s away from the camera (synthetic crossing-s45; tracking.md, "Session 57").
#: 2, 4 and 5 measured.
OFF_LINE_SIGMAS: float = 3.0


@dataclass(frozen=True)
class CornerVelocity:
    """Per piece: the median velocity (n, 2) of the corners on it, its doubt (n,) and their number (n,);
    and the median of their speeds across the line of sight (signed, n) with its own doubt (n,)."""

    velocity: NDArray
    sigma: NDArray
    count: NDArray
    across: NDArray
    across_sigma: NDArray
    mover: NDArray | None = None  # (n, 3): the largest group moving across the line of sight (``_movers``)


class CornerHistory:
    """Each followed corner's last ``HISTORY`` world positions (x, y) and times, by id.

    The stereo stage drops a corner from a frame whose disparity it could not match (a fifth of a
    walker's corners a frame on synthetic urban) while it goes on following it in the image; such a
    corner keeps its history for ``MAX_GAP`` frames, since its id can only come back on the same
    surface.

    Rows stay where they are from frame to frame, sorted by id: a corner's positions go round a
    ring of ``HISTORY`` slots (``w``: how many it has written), and a forgotten corner's row stays,
    empty (``n`` 0), until half the rows are empty. Merging this frame's ids into fresh arrays with
    every history shifted by a slot took 0.47 ms a frame for 3,950 corners (new pages to fill each
    frame), a sixth of the tracker's time with 50 obstacles; in place the update takes 0.07 ms.
    """

    def __init__(self) -> None:
        self.epoch = -1
        #: corner_owners.py's dense grid, every cell -1 between calls: a fresh one a call cost its pages
        #: (262,144 cells of int32) each frame
        self.grid = np.full(GRID_CELLS, -1, dtype=np.int32)
        self._reset()

    def _reset(self, capacity: int = 1024) -> None:
        self._rows = 0
        self._ids = np.zeros(capacity, dtype=np.int64)
        self._xy = np.zeros((capacity, HISTORY, 2))
        self._t = np.zeros((capacity, HISTORY))
        self._n = np.zeros(capacity, dtype=np.int64)
        self._w = np.zeros(capacity, dtype=np.int64)
        self._missed = np.zeros(capacity, dtype=np.int64)
        self._now = np.full((capacity, 3), np.nan)
        self._std = np.zeros(capacity)
        self._fit = np.zeros((capacity, FIT))
        self._views()

    def _views(self) -> None:
        r = self._rows
        self.ids = self._ids[:r]
        self.xy = self._xy[:r]  # ring: a row's last ``n`` positions end at slot ``(w - 1) % HISTORY``
        self.t = self._t[:r]
        self.n = self._n[:r]  # positions held; 0: an empty row
        self.w = self._w[:r]
        self.missed = self._missed[:r]  # frames since last seen; 0: seen this frame
        self.now = self._now[:r]  # world position where seen this frame
        self.std = self._std[:r]  # its range's doubt (m, one sigma), as last seen
        self.fit = self._fit[:r]  # the line through its positions, as ``_line`` fits it when written

    def _arrays(self) -> tuple[NDArray, ...]:
        return self._ids, self._xy, self._t, self._n, self._w, self._missed, self._now, self._std, self._fit

    def _resize(self, keep: NDArray | slice, capacity: int) -> None:
        """The rows ``keep`` moved to the front of arrays of ``capacity`` rows."""
        moved = [a[keep] for a in self._arrays()]
        self._reset(capacity)
        for old, new in zip(moved, self._arrays(), strict=True):
            new[: len(old)] = old
        self._rows = len(moved[0])
        self._views()

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
        if self._rows + len(ids) > len(self._ids):
            self._resize(slice(0, self._rows), 2 * (self._rows + len(ids)))
        if not _in_order(self.ids, ids):  # an id below the last row's that has no row: rows in between
            self._insert(ids)
        rows, empty = _record(*self._arrays(), self._rows, ids, xyz, std, clock, MAX_GAP, OFF_LINE_SIGMAS)
        self._rows = rows
        self._views()
        if empty > max(64, rows // 2):
            self._resize(np.flatnonzero(self.n > 0), len(self._ids))

    def _insert(self, ids: NDArray) -> None:
        """Empty rows, in id order, for ``ids`` below the last row's that have none (a corner first
        passed on long after it was found, or a restarted stereo stage counting from 0 again): the
        rows above move down in place, into the room ``update`` made for all of ``ids``."""
        rows = self._rows
        at = np.minimum(np.searchsorted(self.ids, ids), max(rows - 1, 0))
        extra = ids[(ids < self.ids[rows - 1]) & (self.ids[at] != ids)] if rows else ids[:0]
        _spread(*self._arrays(), rows, extra)
        self._rows = rows + len(extra)
        self._views()


@numba.njit(cache=True)
def _spread(
    ids: NDArray, xy: NDArray, t: NDArray, n: NDArray, w: NDArray, missed: NDArray, now: NDArray, std: NDArray,
    fit: NDArray, rows: int, extra: NDArray,
) -> None:  # fmt: skip
    """Rows for the sorted ``extra`` ids among the first ``rows`` (sorted, none of them there), each
    row moved down by the number of extra ids above it, from the last row up. A full rebuild
    (union, new arrays) took 0.6 ms a frame in the voxel mapper, which follows every corner above
    the road."""
    k = extra.shape[0]
    i = rows - 1
    for dest in range(rows + k - 1, -1, -1):
        if k > 0 and (i < 0 or extra[k - 1] > ids[i]):
            k -= 1
            ids[dest], n[dest], w[dest], missed[dest] = extra[k], 0, 0, 0
            now[dest, 0] = now[dest, 1] = now[dest, 2] = np.nan
            continue
        if dest == i:
            break  # the rows above are where they were
        ids[dest], n[dest], w[dest], missed[dest], std[dest] = ids[i], n[i], w[i], missed[i], std[i]
        xy[dest], t[dest], now[dest], fit[dest] = xy[i], t[i], now[i], fit[i]
        i -= 1


@numba.njit(cache=True)
def _in_order(ids: NDArray, new_ids: NDArray) -> bool:
    """Whether every id in ``new_ids`` either has a row or comes after the last row's: ``_record``
    then only appends rows."""
    last = ids[ids.shape[0] - 1] if ids.shape[0] > 0 else np.iinfo(np.int64).min
    i = 0
    for j in range(new_ids.shape[0]):
        if new_ids[j] > last:
            return True
        while ids[i] < new_ids[j]:
            i += 1
        if ids[i] != new_ids[j]:
            return False
    return True


@numba.njit(cache=True)
def _record(
    ids: NDArray, xy: NDArray, t: NDArray, n: NDArray, w: NDArray, missed: NDArray, now: NDArray, std: NDArray,
    fit: NDArray, rows: int, new_ids: NDArray, new_xyz: NDArray, new_std: NDArray, clock: float, max_gap: int,
    off_line_sigmas: float,
) -> tuple[int, int]:  # fmt: skip
    """This frame's corners written into their rows in place (``_in_order`` holds), new ones appended
    after the last; an unseen corner is kept as it was for ``max_gap`` frames, then its row emptied.
    A written row's line is fitted once here (``fit``): the next frame's off-line test and this
    frame's velocities read it; each fitting it again took 7 % of the tracker's time with 50 obstacles.
    The rows now used, and how many of them are empty."""
    j, empty = 0, 0
    for i in range(rows + new_ids.shape[0]):
        if i >= rows:  # past the last row: the rest are new
            if j >= new_ids.shape[0]:
                break
            ids[i], n[i] = new_ids[j], 0
            rows += 1
        if j < new_ids.shape[0] and new_ids[j] == ids[i]:
            gate = off_line_sigmas * max(new_std[j], std[i])
            if gate > 0.0 and n[i] >= 3 and _off_line(fit, i, new_xyz[j, 0], new_xyz[j, 1], clock) > gate:
                n[i] = 0  # slid onto another surface (an occluding edge): starts again there
            if n[i] == 0:  # new, or forgotten and back: starts again
                w[i] = 0
            k = w[i] % HISTORY
            xy[i, k, 0], xy[i, k, 1], t[i, k] = new_xyz[j, 0], new_xyz[j, 1], clock
            w[i] += 1
            n[i] = min(n[i] + 1, HISTORY)
            missed[i], std[i] = 0, new_std[j]
            now[i, 0], now[i, 1], now[i, 2] = new_xyz[j, 0], new_xyz[j, 1], new_xyz[j, 2]
            fit[i, 0], fit[i, 1], fit[i, 2], fit[i, 3], fit[i, 4], fit[i, 5] = _line(xy, t, n[i], w[i], i)
            j += 1
            continue
        now[i, 0] = now[i, 1] = now[i, 2] = np.nan
        if n[i] > 0 and missed[i] < max_gap:
            missed[i] += 1
        else:
            n[i], missed[i] = 0, max_gap + 1
            empty += 1
    return rows, empty


@numba.njit(cache=True)
def _line(xy: NDArray, t: NDArray, n: int, w: int, r: int) -> tuple[float, float, float, float, float, float]:
    """Row ``r``'s least-squares line through its last ``n`` positions (a ring that ``w`` writes have
    gone round: ``CornerHistory``): mean time, mean x and y, the slopes of x and y, and sum (t - mean t)^2."""
    t_mean = x_mean = y_mean = 0.0
    for q in range(w - n, w):  # oldest first
        k = q % HISTORY
        t_mean += t[r, k]
        x_mean += xy[r, k, 0]
        y_mean += xy[r, k, 1]
    t_mean, x_mean, y_mean = t_mean / n, x_mean / n, y_mean / n
    tt = tx = ty = 0.0
    for q in range(w - n, w):
        k = q % HISTORY
        d = t[r, k] - t_mean
        tt += d * d
        tx += d * (xy[r, k, 0] - x_mean)
        ty += d * (xy[r, k, 1] - y_mean)
    tt = max(tt, 1e-12)
    return t_mean, x_mean, y_mean, tx / tt, ty / tt, tt


@numba.njit(cache=True)
def _off_line(fit: NDArray, r: int, x: float, y: float, clock: float) -> float:
    """How far (m) a new position at ``clock`` lies from where row ``r``'s line (``fit``) puts it."""
    t_mean, x_mean, y_mean, vx, vy = fit[r, 0], fit[r, 1], fit[r, 2], fit[r, 3], fit[r, 4]
    return np.hypot(x - (x_mean + vx * (clock - t_mean)), y - (y_mean + vy * (clock - t_mean)))


@numba.njit(cache=True)
def _fit_lines(fit: NDArray, rows: NDArray) -> tuple[NDArray, NDArray]:
    """Least-squares slopes of x and y against time over each row's last ``n`` positions (as
    ``_record`` fitted them), and the factor 1 / sqrt(sum (t - mean t)^2) that turns a position's
    doubt into the slope's."""
    slope, factor = np.zeros((rows.shape[0], 2)), np.zeros(rows.shape[0])
    for i in range(rows.shape[0]):
        r = rows[i]
        slope[i, 0], slope[i, 1] = fit[r, 3], fit[r, 4]
        factor[i] = 1.0 / np.sqrt(fit[r, 5])
    return slope, factor


def corner_velocity(
    history: CornerHistory, voxels: NDArray, counts: NDArray, slot: NDArray, pieces: int, edge: float, min_samples: int,
    eye: NDArray, across_std_m: float = 0.0, lead: CornerLead = NO_LEAD, mover_from_mps: float = 0.0,
    mover_tol_mps: float = 0.0,
) -> CornerVelocity:
    """Per piece (``0 .. pieces - 1``): its corners (those in its voxels this frame) and their median velocity.

    ``voxels`` are clusters' voxels in a row (anchor.py's ``Footprint``), ``counts`` how many each
    cluster has and ``slot`` which piece each cluster is (-1: none): the tracker's observed clusters
    are stacked once a frame for their anchors, and only the associated ones are pieces. ``lead``:
    when a piece's corners' velocity is carried to this frame (``CornerLead``). ``mover_from_mps``
    over 0: each piece's largest group of corners moving across the line of sight (``_movers``).
    """
    owner = np.repeat(np.asarray(slot, dtype=np.int64), counts)
    if pieces == 0 or len(owner) == 0 or len(history.ids) == 0:
        none = np.full(pieces, np.inf)
        return CornerVelocity(
            np.zeros((pieces, 2)), none, np.zeros(pieces, dtype=np.int64), np.zeros(pieces), none, np.zeros((pieces, 3))
        )
    eye = np.asarray(eye, dtype=np.float64)
    velocity, spread, stereo, count, across, across_spread, across_factor, mover = _piece_velocities(
        np.ascontiguousarray(voxels), owner, history.now, history.n, history.missed, max(min_samples, 2), edge,
        history.fit, history.std, pieces, eye, history.grid, history.xy, history.t, history.w,
        float(lead.sigmas), float(lead.min_mps), int(lead.samples), float(mover_from_mps), float(mover_tol_mps),
    )  # fmt: skip
    m = np.maximum(count, 1).astype(np.float64)
    shrink = np.sqrt(SHARED + (1.0 - SHARED) / m)
    sigma = np.maximum(MAD_SIGMA * spread / np.sqrt(m), stereo * shrink)
    across_sigma = np.maximum(MAD_SIGMA * across_spread / np.sqrt(m), across_std_m * across_factor * shrink)
    if across_std_m <= 0.0:
        across_sigma[:] = np.inf
    known = count > 0
    return CornerVelocity(
        velocity, np.where(known, sigma, np.inf), count, across, np.where(known, across_sigma, np.inf), mover
    )


@numba.njit(cache=True)
def _piece_velocities(
    voxels: NDArray, owner: NDArray, now: NDArray, n: NDArray, missed: NDArray, min_n: int, edge: float,
    fit: NDArray, std: NDArray, pieces: int, eye: NDArray, grid: NDArray, xy: NDArray, t: NDArray, w: NDArray,
    lead_sigmas: float, lead_min_mps: float, lead_samples: int, mover_from: float, mover_tol: float,
) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray, NDArray, NDArray, NDArray]:  # fmt: skip
    """Per piece, from the corners seen this frame with ``min_n`` positions or more that lie in one of
    its voxels (``voxels`` in a row, ``owner`` says whose; -1: nobody's; of two, the lower): the
    median of their lines' velocities (x, y), the median distance from it, the median doubt their
    ranges bring, and how many; then the median of their speeds across the line of sight from
    ``eye`` (signed), the median distance from it, and the median factor that turns a position's
    doubt into their lines'; and, with ``mover_from`` over 0, the largest group moving across it
    (``_movers``).

    Which piece each corner is on comes from corner_owners.py (``grid``: its scratch). With
    ``lead_sigmas`` over 0 a piece's lines are first carried to this frame (common/corner_lead.py):
    ``xy``, ``t`` and ``w`` are the history's rings.
    """
    whose, count = owners(voxels, owner, now, n, missed, min_n, edge, pieces, grid)
    start = np.zeros(pieces + 1, np.int64)
    start[1:] = np.cumsum(count)
    fill, members = start[:-1].copy(), np.empty(start[-1], np.int64)
    for c in range(now.shape[0]):
        if whose[c] >= 0:
            members[fill[whose[c]]] = c
            fill[whose[c]] += 1
    slope, factor = _fit_lines(fit, members)
    if lead_sigmas > 0.0:
        carry(slope, members, start, xy, t, n, w, lead_sigmas, lead_min_mps, lead_samples)
    doubt, off = np.empty(members.shape[0]), np.empty(members.shape[0])
    side = np.empty(members.shape[0])  # each corner's speed across its line of sight from the eye
    ray = np.empty((members.shape[0], 2))
    for i in range(members.shape[0]):
        c = members[i]
        doubt[i] = std[c] * factor[i]
        rx, ry = now[c, 0] - eye[0], now[c, 1] - eye[1]
        ray[i, 0], ray[i, 1] = rx, ry
        norm = max(np.sqrt(rx * rx + ry * ry), 1e-9)
        side[i] = (-ry * slope[i, 0] + rx * slope[i, 1]) / norm
    velocity, spread, stereo = np.zeros((pieces, 2)), np.zeros(pieces), np.zeros(pieces)
    across, across_spread, across_factor = np.zeros(pieces), np.zeros(pieces), np.zeros(pieces)
    scratch, pick = np.empty(max(1, members.shape[0])), np.empty(max(1, members.shape[0]))
    mover = np.zeros((pieces, 3))
    for p in range(pieces):
        if count[p] == 0:
            continue
        a, b = start[p], start[p + 1]
        if mover_from > 0.0:
            mover[p, 0], mover[p, 1], mover[p, 2] = _movers(side, ray, a, b, mover_from, mover_tol, pick, scratch)
        vx, vy = median(slope[a:b, 0], scratch), median(slope[a:b, 1], scratch)
        velocity[p, 0], velocity[p, 1] = vx, vy
        for i in range(a, b):
            off[i] = np.sqrt((slope[i, 0] - vx) ** 2 + (slope[i, 1] - vy) ** 2)
        spread[p] = median(off[a:b], scratch)
        stereo[p] = median(doubt[a:b], scratch)
        va = median(side[a:b], scratch)
        across[p] = va
        for i in range(a, b):
            off[i] = abs(side[i] - va)
        across_spread[p] = median(off[a:b], scratch)
        across_factor[p] = median(factor[a:b], scratch)
    return velocity, spread, stereo, count, across, across_spread, across_factor, mover


@numba.njit(cache=True)
def _movers(
    side: NDArray, ray: NDArray, a: int, b: int, from_mps: float, tol: float, pick: NDArray, scratch: NDArray
) -> tuple[float, float, float]:
    """Of corners ``a .. b - 1``: the largest group moving one way across the line of sight at
    ``from_mps`` or more, within ``tol`` of its median: how many, their median speed across (signed)
    and how wide they lie across the line of sight (m; ``ray``: each one's from the eye).

    A walker beside a wall at 15-25 m shares its cluster (a voxel apart, colours alike after the
    smear mixes them), and the wall's corners outvote his in the median; across the line of sight
    each corner's speed is sure to a few centimetres a second, whatever its range's error.
    """
    best_k, best_v, best_w = 0, 0.0, 0.0
    for sign in (1.0, -1.0):
        m = 0
        for i in range(a, b):
            if sign * side[i] >= from_mps:
                pick[m] = side[i]
                m += 1
        if m <= best_k:
            continue
        centre = median(pick[:m], scratch)
        k, ux, uy = 0, 0.0, 0.0
        for i in range(a, b):
            if sign * side[i] >= from_mps and abs(side[i] - centre) <= tol:
                pick[k] = side[i]
                k += 1
                ux += ray[i, 0]
                uy += ray[i, 1]
        if k <= best_k:
            continue
        norm = max(np.sqrt(ux * ux + uy * uy), 1e-9)
        ux, uy = ux / norm, uy / norm
        lo, hi = np.inf, -np.inf
        for i in range(a, b):
            if sign * side[i] >= from_mps and abs(side[i] - centre) <= tol:
                x = uy * ray[i, 0] - ux * ray[i, 1]
                lo, hi = min(lo, x), max(hi, x)
        best_k, best_v, best_w = k, median(pick[:k], scratch), hi - lo
    return float(best_k), best_v, best_w
