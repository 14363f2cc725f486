"""The point of a cluster the filter follows: its faces turned to the camera, not its centroid.

Driving past a parked car, the part of it in view changes every frame: first its rear, then its
side as well, then only the side as the rear leaves the image. Its centroid slides along the car
at up to half the vehicle's speed although the car stands still (measured on synthetic urban,
8-frame windows: median drift 0.53 m/s, 36 % of windows over 0.7 m/s). The faces that look at the
camera stay put while they are in view: the near end along the vehicle's x, and the side facing
the road along its y (or the middle, for an object straddling the line of sight). A low or high
percentile of the voxels, rather than the box limit, keeps one stray voxel from moving it. The
same windows drift by a median of 0.31 m/s (24 % over 0.7 m/s) on these faces, and a moving
object is followed as well as by its centroid. Height is the centroid's: nothing slides vertically.

A narrow object (a walker, a pole, a cyclist from behind) is in view whole, so nothing of it
slides in and out of view; what moves its near face instead is stereo smear. Its disparity
spreads along the line of sight into a sparse fringe of voxels before and behind a dense core,
and the fringe's depth changes with range: a walker coming towards the camera at 1.9 m/s walked
2.2 m in 1.2 s while its near face moved less than 0.7 m. Such a cluster is followed at the
median range of this frame's points (the mapper counts them per voxel), which the fringe's few
points hardly move. Moving TP / FP went 68.9 / 2.0 -> 71.5 / 2.2 % on the eight tuning runs and
64.7 / 3.6 -> 66.7 / 1.5 % on the eight held-out ones (docs/results/tracking.md, "Session 14").
Since session 38 it is the interquartile mean of those ranges (``RANGE_TRIM``), which moves as the
points do where the median jumps a voxel at a time.
Narrow is measured across the line of sight: sideways, an oncoming car seen obliquely was narrow
too, and the median of its points slid back along its side as it neared ("Session 22").

The near end is no face of the object where the image's side edge cuts it: a building beside
the road, or a car overtaking into view, shows from where the edge meets it, and that end slides
forward with the vehicle. A cluster whose faces' near corner lies within ``view_margin`` (m,
sideways) of the edges the mapper found (``Clusters.view``), or beyond them, is followed at its
far end instead (``cut``). The corner stands for the voxels: testing every voxel gave the same
held-out figures and cost 2-3 % of the tracker's time. On tuning replays moving labels that were
false went 1.9 -> 1.6 % and overtake's speed RMSE 0.47 -> 0.35 m/s; on KITTI 0001, 5 -> 3 false
moving frames (docs/results/tracking.md, "Session 24").

Which side face is in view changes as an object crosses the line of sight; the three candidates
are all returned so that a track can switch without a jump (core.py shifts its state by the
difference of the two points of the same cluster).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numba
import numpy as np
import numpy.typing as npt

from common.messages import Cluster

NDArray = npt.NDArray[Any]

#: percentile of the voxels taken as a face (low end of the range; the high end is 100 minus it).
FACE_PERCENTILE: float = 5.0
#: a cluster narrower than this across the line of sight (m, 5-95 % of its points) is followed at
#: the middle range of its points (``RANGE_TRIM``) instead of its near face (measured 1.3, 2.0, 2.5).
NARROW_M: float = 2.0
#: ... and so is one this narrow sideways and at least this long (m, 5-95 % of its voxels in
#: vehicle y and x): longer than any vehicle, a structure along the road, whose near end is where the
#: image's side edge cuts it and slides with the vehicle (measured 4.5, 6, 8: the same).
ALONG_ROAD_M: float = 6.0
#: a narrow cluster's range is the mean of its points' ranges between these weighted quantiles
#: (0.25: the interquartile mean; 0 would be the median). The median of voxel cell centres moves in
#: whole voxels, 0.25 m a frame (2.5 m/s at 10 Hz) where a walker moves 0.15 m; the interquartile
#: mean moves as the points do. Tracker replays (docs/results/tracking.md, "Session 38"): held-out
#: moving TP / FP frames 1287 / 40 -> 1302 / 39, tuning 1325 / 38 -> 1330 / 31, fresh 767 / 16 ->
#: 765 / 14 (measured 0.10 and 0.40: 1299 / 45 and 1294 / 36 held out).
RANGE_TRIM: float = 0.25


class Footprint(NamedTuple):
    """Clusters' voxels in a row: stacked once a frame for their anchors, and for the corners on them
    (keypoint_motion.py)."""

    voxels: NDArray  # (k, 3) int64, cluster by cluster
    counts: NDArray  # (n,) how many each cluster has
    weights: NDArray  # (k,) this frame's points per voxel (+ 1e-3), or 1 where the cluster has no counts
    counted: NDArray  # (n,) which clusters' voxels have their points counted


def footprint(clusters: list[Cluster]) -> Footprint:
    """All clusters' voxels in a row, their counts, this frame's points per voxel, and which are counted.

    A cluster from a recording made before the mapper counted points weighs its voxels alike. The
    arrays are joined as they come (one concatenation each): reshaping each cluster's first cost
    twice as much with 50 clusters.
    """
    voxels = [c.voxels for c in clusters]
    points = [c.voxel_points for c in clusters]
    counts = np.array([len(v) for v in voxels], dtype=np.int64)
    counted = np.array([len(w) for w in points], dtype=np.int64) == counts
    if not counted.all():
        points = [w if ok else np.ones(n) for w, ok, n in zip(points, counted, counts.tolist(), strict=True)]
    if not voxels:
        return Footprint(np.zeros((0, 3), np.int64), counts, np.zeros(0), counted)
    try:
        stacked = np.concatenate(voxels).astype(np.int64).reshape(-1, 3)
    except ValueError:  # an empty cluster's voxels as a flat list
        stacked = np.concatenate([np.asarray(v).reshape(-1, 3) for v in voxels]).astype(np.int64)
    weights = np.concatenate(points).astype(np.float64)
    # + 1e-3: a voxel kept without points this frame counts a little
    if counted.all():
        return Footprint(stacked, counts, weights + 1e-3, counted)
    return Footprint(stacked, counts, np.where(np.repeat(counted, counts), weights + 1e-3, weights), counted)


@numba.njit(cache=True)
def _order(values: NDArray) -> NDArray:
    """The ascending order of ``values``: counted into two bins a value, then put right within bins.

    Exact, and stable. numba's quicksort took 0.8 µs for a cluster's 84 values where this takes
    0.5, and the anchors sorted three times a cluster, 150 times a frame with 50 obstacles.
    """
    m = values.shape[0]
    order = np.arange(m)
    if m < 2:
        return order
    lo = hi = values[0]
    for i in range(1, m):
        lo, hi = min(lo, values[i]), max(hi, values[i])
    bins = 2 * m
    width = (hi - lo) / bins
    if not 0.0 < width < np.inf:  # all alike: any order is sorted (and none is taken from a bin off the end)
        return np.argsort(values) if width != 0.0 else order
    start = np.zeros(bins + 1, np.int64)
    key = np.empty(m, np.int64)
    for i in range(m):
        key[i] = min(max(int((values[i] - lo) / width), 0), bins - 1)
        start[key[i] + 1] += 1
    for b in range(bins):
        start[b + 1] += start[b]
    for i in range(m):
        order[start[key[i]]] = i
        start[key[i]] += 1
    for i in range(1, m):  # insertion: values out of place only within their bin
        o, j = order[i], i
        while j > 0 and values[order[j - 1]] > values[o]:
            order[j] = order[j - 1]
            j -= 1
        order[j] = o
    return order


#: a selection keeps the ``k`` + 1 smallest (or largest) values in a buffer up to this ``k``; past it, sorts.
SELECT_MAX: int = 32


@numba.njit(cache=True)
def _kth(values: NDArray, k: int, buffer: NDArray) -> float:
    """The ``k``-th smallest of ``values`` (0-based), as ``values[_order(values)[k]]``, without a sort
    where ``k`` lies near either end: a face's 5 % of a cluster's voxels is its fifth value of 84."""
    m = values.shape[0]
    top = m - 1 - k
    if min(k, top) > SELECT_MAX:
        return values[_order(values)[k]]
    low = k <= top
    keep = (k if low else top) + 1
    held = 0
    for i in range(m):
        v = values[i] if low else -values[i]
        if held == keep and v >= buffer[held - 1]:
            continue
        j = held if held < keep else keep - 1
        while j > 0 and buffer[j - 1] > v:
            buffer[j] = buffer[j - 1]
            j -= 1
        buffer[j] = v
        held = min(held + 1, keep)
    return buffer[keep - 1] if low else -buffer[keep - 1]


@numba.njit(cache=True)
def _pick(
    values: NDArray,
    weights: NDArray,
    start: int,
    running: float,
    by_voxels: NDArray,
    by_points: NDArray,
    out: NDArray,
    trim: float,
) -> float:
    """One cluster's percentiles of ``values`` into ``out``, by voxels then by points; the points summed so far.

    By voxels, the first value (ascending) whose running count reaches the share; by points, the
    first whose running points do. With ``trim`` > 0, the last slot of ``out`` takes the mean of the
    values between the points' ``trim`` and ``1 - trim`` shares, each value counted with the part of
    its points inside: it moves smoothly as points shift from one voxel to the next, where a
    percentile jumps a whole voxel. ``running`` carries the points of the clusters before this one,
    so the sums are those of one cumulative sum over the frame, as in the all-numpy form this
    replaced (the same figures on every replay, docs/results/tracking.md, "Session 30").
    """
    m = values.shape[0]
    order = _order(values)
    for j, share in enumerate(by_voxels):
        # rounded at the frame-wide position, as the all-numpy form did, so that it rounds alike
        k = int(np.ceil(start + share * m)) - 1 - start
        out[j] = values[order[min(max(k, 0), m - 1)]]
    if by_points.shape[0] > 0:
        before = running
        cum = np.empty(m)
        for i in range(m):
            running += weights[order[i]]
            cum[i] = running
        total = running - before
        for j, share in enumerate(by_points):
            k = np.searchsorted(cum, before + share * total)
            out[by_voxels.shape[0] + j] = values[order[min(max(k, 0), m - 1)]]
        if trim > 0.0:
            lo, hi, num, den = before + trim * total, before + (1.0 - trim) * total, 0.0, 0.0
            for i in range(m):
                part = min(cum[i], hi) - max(cum[i] - weights[order[i]], lo)
                if part > 0.0:
                    num += part * values[order[i]]
                    den += part
            out[by_voxels.shape[0] + by_points.shape[0]] = num / den if den > 0.0 else values[order[m // 2]]
    return running


@numba.njit(cache=True)
def _middle_half(values: NDArray, weights: NDArray, step: float) -> float:
    """How far apart the weighted 25 % and 75 % of ``values`` lie, to within ``step``, without sorting.

    The values are binned ``step`` apart (coarser if that would take over 1024 bins) and each
    quantile read off the running weights by linear interpolation within its bin: a sort of every
    narrow cluster's voxels cost the tracker 5 % of its time.
    """
    lo, hi = values.min(), values.max()
    bins = min(int((hi - lo) / step) + 1, 1024)
    width = max((hi - lo) / bins, 1e-9)
    mass = np.zeros(bins)
    for i in range(values.shape[0]):
        mass[min(int((values[i] - lo) / width), bins - 1)] += weights[i]
    total = mass.sum()
    ends = np.empty(2)
    for j, share in enumerate((0.25, 0.75)):
        target, running = share * total, 0.0
        for b in range(bins):
            if running + mass[b] >= target and mass[b] > 0.0:
                ends[j] = lo + width * (b + (target - running) / mass[b])
                break
            running += mass[b]
        else:
            ends[j] = hi
    return ends[1] - ends[0]


@numba.njit(cache=True)
def _place(
    voxels: NDArray,
    counts: NDArray,
    weights: NDArray,
    counted: NDArray,
    centroids: NDArray,
    pose: NDArray,
    edge: float,
    q: float,
    narrow_m: float,
    along_road_m: float,
    view: NDArray,
    view_margin: float,
    trim: float,
) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray, NDArray]:
    """``anchors`` for clusters with voxels under a finite pose, one cluster at a time.

    Each cluster's own voxels are sorted on their own: in numpy, sorting all the frame's voxels
    by (cluster, value) three times, with the gathers and the per-cluster arithmetic around it,
    took a third of the tracker's time with 50 clusters.
    """
    n = counts.shape[0]
    out = np.empty((n, 3, 3))
    side = np.ones(n, dtype=np.int8)
    far = np.zeros((n, 3))
    narrow = np.zeros(n, dtype=np.bool_)
    cut = np.zeros(n, dtype=np.bool_)
    sizes = np.full((n, 2), np.nan)  # across the line of sight and, if narrow, the core's depth along it
    faces, median, tails, none = np.array([q, 1.0 - q]), np.array([0.5]), np.array([0.05, 0.95]), np.zeros(0)
    xs, ys, spread, buffer = np.empty(4), np.empty(2), np.empty(2), np.empty(SELECT_MAX + 1)
    r, o = pose[0:3, 0:3], pose[0:3, 3]
    run_x, run_across = 0.0, 0.0
    start = 0
    for c in range(n):
        m = counts[c]
        for s in range(3):
            out[c, s] = centroids[c]
        if m == 0:
            continue
        rel = centroids[c] - o
        # across the line of sight, not sideways: a car seen obliquely is 1.8 m wide in y but shows
        # its side, and its points' median range slides back along it as it nears (oncoming cars
        # were read at 65-75 % of their speed); a walker smeared along an oblique ray is wide in y
        ray_x = rel[0] * r[0, 0] + rel[1] * r[1, 0] + rel[2] * r[2, 0]
        ray_y = rel[0] * r[0, 1] + rel[1] * r[1, 1] + rel[2] * r[2, 1]
        norm = max(np.sqrt(ray_x * ray_x + ray_y * ray_y), 1e-9)
        ray_x, ray_y = ray_x / norm, ray_y / norm
        x, y, across = np.empty(m), np.empty(m), np.empty(m)
        for i in range(m):
            w0 = (voxels[start + i, 0] + 0.5) * edge - o[0]
            w1 = (voxels[start + i, 1] + 0.5) * edge - o[1]
            w2 = (voxels[start + i, 2] + 0.5) * edge - o[2]
            x[i] = w0 * r[0, 0] + w1 * r[1, 0] + w2 * r[2, 0]
            y[i] = w0 * r[0, 1] + w1 * r[1, 1] + w2 * r[2, 1]
            across[i] = ray_x * y[i] - ray_y * x[i]
        w = weights[start : start + m]
        run_x = _pick(x, w, start, run_x, faces, median, xs, trim)
        for j in range(2):  # rounded at the frame-wide position, as ``_pick`` does
            k = int(np.ceil(start + faces[j] * m)) - 1 - start
            ys[j] = _kth(y, min(max(k, 0), m - 1), buffer)
        run_across = _pick(across, w, start, run_across, none, tails, spread, 0.0)
        start += m
        near_x, far_x, range_x, y_lo, y_hi = xs[0], xs[1], xs[2], ys[0], ys[1]
        along_road = (y_hi - y_lo < narrow_m) and (far_x - near_x >= along_road_m)
        sizes[c, 0] = spread[1] - spread[0]
        narrow[c] = counted[c] and ((sizes[c, 0] < narrow_m) or along_road)
        if sizes[c, 0] < narrow_m:
            # how deep its points' middle half lies along the line of sight: a walker's core is
            # compact however long his smear's fringe; a wall seen edge-on is deep throughout
            sizes[c, 1] = _middle_half(ray_x * x + ray_y * y, w, 0.125 * edge)
        if trim > 0.0:
            range_x = xs[3]
        front = range_x if narrow[c] else near_x
        z = rel[0] * r[0, 2] + rel[1] * r[1, 2] + rel[2] * r[2, 2]
        for s, side_y in enumerate((y_lo, 0.5 * (y_lo + y_hi), y_hi)):
            for a in range(3):  # the side's point in the vehicle frame, into the world
                out[c, s, a] = r[a, 0] * front + r[a, 1] * side_y + r[a, 2] * z + o[a]
        side[c] = 2 if y_hi < 0.0 else (0 if y_lo > 0.0 else 1)
        for a in range(3):
            far[c, a] = (far_x - front) * r[a, 0]
        if view_margin > 0.0 and view[2] > view[3]:
            # how far inside the image's side edges (m, sideways) the faces' near corners lie; a
            # cluster reaching them has its near end where the edge cuts it, which slides with the vehicle
            dx = near_x - view[0]
            inside = min(view[2] * dx - (y_hi - view[1]), (y_lo - view[1]) - view[3] * dx)
            cut[c] = not narrow[c] and inside <= view_margin
    return out, side, far, narrow, cut, sizes


#: what ``_place`` is given without the mapper's image edges: slopes that fail its test.
NO_VIEW = np.zeros(4)


def anchors(
    clusters: list[Cluster],
    centroids: NDArray,
    pose: NDArray,
    edge: float,
    view: NDArray | None = None,
    view_margin: float = 0.0,
    stacked: Footprint | None = None,
) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray, NDArray]:
    """World points (n, 3 sides, 3), the side in view (n,), the far-end shift (n, 3), which are narrow
    (n,), which are cut by the image's side edge (n,; ``view`` as ``Clusters.view``) and how wide
    their points are across the line of sight and, where that is under ``NARROW_M``, how deep their
    middle half lies along it (n, 2; metres, 5-95 % and 25-75 % of the points; NaN where unknown).

    Side 0 takes the low-y face (object left of the line of sight), 1 the middle (straddling it),
    2 the high-y face (right of it); x is the near face (a narrow cluster's interquartile mean range) and z
    the centroid's in all three. A cluster without voxels, or a frame without a pose, keeps its
    centroid for every side. The far-end shift moves that point to the far end along the
    vehicle's x (the high percentile), the other end of the object: a rigid object's two ends move
    together, a box growing or uncovered at one end moves only that end (motion_window.py).
    A percentile is the first voxel whose running count (or running points) reaches its share.
    ``stacked`` is ``footprint(clusters)``, where the caller has it already.
    """
    n = len(clusters)
    centroids = np.ascontiguousarray(centroids, dtype=np.float64).reshape(n, 3)
    if n == 0 or not np.isfinite(pose).all():
        return (
            np.repeat(centroids[:, None, :], 3, axis=1),
            np.ones(n, dtype=np.int8),
            np.zeros((n, 3)),
            np.zeros(n, dtype=bool),
            np.zeros(n, dtype=bool),
            np.full((n, 2), np.nan),
        )
    voxels, counts, weights, counted = footprint(clusters) if stacked is None else stacked
    # copies: a message decoded off the bus holds read-only arrays, which numba would compile for again
    seen = NO_VIEW if view is None else np.array(view, dtype=np.float64)
    return _place(
        voxels,
        counts,
        weights,
        counted,
        centroids,
        np.array(pose, dtype=np.float64, order="C"),
        float(edge),
        FACE_PERCENTILE / 100.0,
        NARROW_M,
        ALONG_ROAD_M,
        seen,
        float(view_margin),
        RANGE_TRIM,
    )
