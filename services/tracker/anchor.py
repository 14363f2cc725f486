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

from typing import Any

import numpy as np
import numpy.typing as npt

from common.messages import Cluster

NDArray = npt.NDArray[Any]

#: percentile of the voxels taken as a face (low end of the range; the high end is 100 minus it).
FACE_PERCENTILE: float = 5.0
#: a cluster narrower than this across the line of sight (m, 5-95 % of its points) is followed at
#: the median range of its points instead of its near face (measured 1.3, 2.0, 2.5).
NARROW_M: float = 2.0
#: ... and so is one this narrow sideways and at least this long (m, 5-95 % of its voxels in
#: vehicle y and x): longer than any vehicle, a structure along the road, whose near end is where the
#: image's side edge cuts it and slides with the vehicle (measured 4.5, 6, 8: the same).
ALONG_ROAD_M: float = 6.0


def _stacked(clusters: list[Cluster]) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """All clusters' voxels in a row (float), their counts, this frame's points per voxel, and which are counted.

    A cluster from a recording made before the mapper counted points weighs its voxels alike. One
    pass over the clusters: three list comprehensions cost 60 µs a frame with 50 clusters.
    """
    voxels, points = [], []
    for c in clusters:
        voxels.append(np.asarray(c.voxels).reshape(-1, 3))
        points.append(np.asarray(c.voxel_points))
    counts = np.fromiter((len(v) for v in voxels), dtype=np.int64, count=len(voxels))
    counted = np.fromiter((len(w) for w in points), dtype=np.int64, count=len(points)) == counts
    if not counted.all():
        points = [w if ok else np.ones(n) for w, ok, n in zip(points, counted, counts.tolist(), strict=True)]
    stacked = np.concatenate(voxels).astype(np.float64) if voxels else np.zeros((0, 3))
    weights = np.concatenate(points).astype(np.float64) if points else np.zeros(0)
    # + 1e-3: a voxel kept without points this frame counts a little
    return stacked, counts, np.where(np.repeat(counted, counts), weights + 1e-3, weights), counted


def anchors(
    clusters: list[Cluster],
    centroids: NDArray,
    pose: NDArray,
    edge: float,
    view: NDArray | None = None,
    view_margin: float = 0.0,
) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
    """World points (n, 3 sides, 3), the side in view (n,), the far-end shift (n, 3), which are narrow
    (n,) and which are cut by the image's side edge (n,; ``view`` as ``Clusters.view``).

    Side 0 takes the low-y face (object left of the line of sight), 1 the middle (straddling it),
    2 the high-y face (right of it); x is the near face (a narrow cluster's median range) and z
    the centroid's in all three. A cluster without voxels, or a frame without a pose, keeps its
    centroid for every side. The far-end shift moves that point to the far end along the
    vehicle's x (the high percentile), the other end of the object: a rigid object's two ends move
    together, a box growing or uncovered at one end moves only that end (motion_window.py).
    A percentile is the first voxel whose running count (or running points) reaches its share,
    taken for every cluster at once from one sort of all voxels by (cluster, value): per-cluster
    ``np.quantile`` calls cost 25 ms for 50 clusters.
    """
    n = len(clusters)
    out = np.repeat(np.asarray(centroids, dtype=np.float64)[:, None, :], 3, axis=1)
    side = np.ones(n, dtype=np.int8)
    far = np.zeros((n, 3))
    narrow = np.zeros(n, dtype=bool)
    cut = np.zeros(n, dtype=bool)
    if n == 0 or not np.isfinite(pose).all():
        return out, side, far, narrow, cut
    voxels, counts, weights, counted = _stacked(clusters)
    if len(voxels) == 0:
        return out, side, far, narrow, cut
    rotation, origin = pose[0:3, 0:3], pose[0:3, 3]
    # vehicle x, y of every voxel; np.dot with the scale folded in: ``@`` on (n, 3) x (3, 2) is 4x slower here
    axes = np.ascontiguousarray(rotation[:, 0:2])
    local = np.dot(voxels, edge * axes) + (0.5 * edge - origin) @ axes
    label = np.repeat(np.arange(n), counts)
    has = counts > 0
    ends = np.cumsum(counts)
    starts = np.minimum(ends - counts, len(voxels) - 1)
    last = np.maximum(ends - 1, starts)

    def ranked(values: NDArray, by_voxels: tuple[float, ...], by_points: tuple[float, ...]) -> list[NDArray]:
        """Per cluster, the first value (ascending) whose running count, then running points, reach each share.

        One sort serves both: the faces count voxels, a narrow cluster's range and width its points.
        The running count is the position itself, so its share is found without a search.
        """
        low = values.min()
        order = np.argsort(label * (float(values.max() - low) + 1.0) + (values - low), kind="stable")
        ordered = values[order]
        at = [np.ceil(starts + share * counts).astype(np.int64) - 1 for share in by_voxels]
        out = [ordered[np.clip(i, starts, last)] for i in at]
        if by_points:
            cum = np.cumsum(weights[order])
            before = np.where(starts > 0, cum[np.maximum(starts - 1, 0)], 0.0)
            total = cum[last] - before
            out += [ordered[np.clip(np.searchsorted(cum, before + share * total), starts, last)] for share in by_points]
        return out

    q = FACE_PERCENTILE / 100.0
    near_x, far_x, range_x = ranked(local[:, 0], (q, 1.0 - q), (0.5,))
    y_lo, y_hi = ranked(local[:, 1], (q, 1.0 - q), ())
    # across the line of sight, not sideways: a car seen obliquely is 1.8 m wide in y but shows its
    # side, and its points' median range slides back along it as it nears (oncoming cars were
    # read at 65-75 % of their speed); a walker smeared along an oblique ray is wide in y
    ray = (out[:, 0, 0:3] - origin) @ axes
    ray /= np.maximum(np.linalg.norm(ray, axis=1), 1e-9)[:, None]
    across_lo, across_hi = ranked(ray[label, 0] * local[:, 1] - ray[label, 1] * local[:, 0], (), (0.05, 0.95))
    along_road = (y_hi - y_lo < NARROW_M) & (far_x - near_x >= ALONG_ROAD_M)
    narrow[:] = counted & ((across_hi - across_lo < NARROW_M) | along_road) & has
    x = np.where(narrow, range_x, near_x)
    z = (out[:, 0] - origin) @ rotation[:, 2]
    # the three sides' points in the vehicle frame (n, 3 sides, 3), then all into the world at once
    points = np.empty((n, 3, 3))
    points[:, :, 0] = x[:, None]
    points[:, :, 1] = np.column_stack([y_lo, 0.5 * (y_lo + y_hi), y_hi])
    points[:, :, 2] = z[:, None]
    out[has] = (points @ rotation.T + origin)[has]
    side[has] = np.where(y_hi < 0.0, 2, np.where(y_lo > 0.0, 0, 1))[has]
    far[has] = ((far_x - x)[:, None] * rotation[:, 0][None, :])[has]
    if view is not None and view_margin > 0.0 and view[2] > view[3]:
        # how far inside the image's side edges (m, sideways) the faces' near corners lie; a cluster
        # reaching them has its near end where the edge cuts it, which slides with the vehicle
        dx = near_x - view[0]
        inside = np.minimum(view[2] * dx - (y_hi - view[1]), (y_lo - view[1]) - view[3] * dx)
        cut = has & ~narrow & (inside <= view_margin)
    return out, side, far, narrow, cut
