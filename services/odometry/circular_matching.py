"""The paper's circle: last-left -> last-right -> previous-right -> previous-left -> last-left.

Each leg is a best-match search under a geometric constraint: stereo legs on the same rectified row
(within ``row_tol``) with positive disparity in range, temporal legs inside a window around where
the feature is expected to be. A feature survives only when following the four best matches brings
it back to itself, which discards most ambiguous matches without any ratio threshold
(Geiger et al., StereoScan, 2011).

Candidate pairs are enumerated sparsely (features sorted by row, windows expanded with numpy), so
the cost grows with the number of plausible pairs rather than with the square of the features.
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from services.odometry.features import Features

Index = npt.NDArray[np.intp]
_NONE = -1
_SHIFT = 22  # bits kept for an index inside the packed (distance, index) key
SAD_CHUNK = 65536  # descriptor pairs compared at once (bounds the memory of a search without prior)


def candidate_pairs(
    query_xy: npt.NDArray[np.floating], target_xy: npt.NDArray[np.floating], rx: float, ry: float
) -> tuple[Index, Index]:
    """All (query, target) index pairs with |dx| <= rx and |dy| <= ry.

    Targets are sorted by (row band, x); each query looks up the exact x interval in each band
    its y window touches, so only pairs already inside the window in x are ever formed.
    """
    if len(query_xy) == 0 or len(target_xy) == 0:
        empty = np.zeros(0, dtype=np.intp)
        return empty, empty
    band = max(1.0, ry / 2.0)
    span = float(max(target_xy[:, 0].max(), query_xy[:, 0].max()) + 2 * rx + 2)
    t_band = np.floor(target_xy[:, 1] / band)
    key = t_band * span + (target_xy[:, 0] + rx + 1)
    order = np.argsort(key, kind="stable")
    key = key[order]
    first = np.floor((query_xy[:, 1] - ry) / band)
    last = np.floor((query_xy[:, 1] + ry) / band)
    bands = int((last - first).max()) + 1
    rows = first[:, None] + np.arange(bands)[None, :]  # M x bands
    qx = query_xy[:, 0:1] + rx + 1
    lo = np.searchsorted(key, rows * span + qx - rx, side="left")
    hi = np.searchsorted(key, rows * span + qx + rx, side="right")
    hi = np.where(rows <= last[:, None], hi, lo)
    counts = (hi - lo).ravel()
    total = int(counts.sum())
    query = np.repeat(np.repeat(np.arange(len(query_xy)), bands), counts)
    offsets = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    target = order[np.repeat(lo.ravel(), counts) + offsets]
    near = np.abs(target_xy[target, 1] - query_xy[query, 1]) <= ry
    return query[near], target[near]


def sad(a: npt.NDArray[np.uint8], b: npt.NDArray[np.uint8], ia: Index, ib: Index) -> npt.NDArray[np.int64]:
    """Sum of absolute descriptor differences for the pairs (ia[k], ib[k]).

    In slices of ``SAD_CHUNK`` pairs: a search without a motion prior (a lost track, a replay
    that loops) forms about a million pairs, whose gathered descriptors alone took 230 MB at once.
    """
    out = np.empty(len(ia), dtype=np.int64)
    for start in range(0, len(ia), SAD_CHUNK):
        part = slice(start, start + SAD_CHUNK)
        diff = cv2.absdiff(a.take(ia[part], axis=0), b.take(ib[part], axis=0))
        out[part] = cv2.reduce(diff, 1, cv2.REDUCE_SUM, dtype=cv2.CV_32S).ravel()
    return out


def best_of(group: Index, other: Index, cost: npt.NDArray[np.int64], size: int) -> Index:
    """For each of ``size`` items, the ``other`` of its cheapest pair (-1 where it has none)."""
    best = np.full(size, np.iinfo(np.int64).max, dtype=np.int64)
    np.minimum.at(best, group, (cost << _SHIFT) | other)
    out = np.full(size, _NONE, dtype=np.intp)
    found = best != np.iinfo(np.int64).max
    out[found] = best[found] & ((1 << _SHIFT) - 1)
    return out


def match_stereo(
    left: Features, right: Features, min_disparity: float, max_disparity: float, row_tol: float
) -> tuple[Index, Index]:
    """Best right match of each left feature and best left match of each right feature.

    Rectified epipolar constraint: same row within ``row_tol`` and x_left - x_right in
    [min_disparity, max_disparity].
    """
    half = 0.5 * (max_disparity - min_disparity)
    shifted = left.xy - np.array([min_disparity + half, 0.0], dtype=np.float32)
    il, ir = candidate_pairs(shifted, right.xy, half, row_tol)
    cost = sad(left.descriptors, right.descriptors, il, ir)
    return best_of(il, ir, cost, len(left)), best_of(ir, il, cost, len(right))


def match_temporal(
    previous: Features, predicted_xy: npt.NDArray[np.floating], current: Features, radius: float
) -> tuple[Index, Index]:
    """Best current match of each previous feature (searched around ``predicted_xy``) and back.

    ``predicted_xy`` is where each previous feature should appear in the current image; rows with
    NaN take no part.
    """
    usable = np.flatnonzero(np.isfinite(predicted_xy).all(axis=1))
    ip, ic = candidate_pairs(predicted_xy[usable], current.xy, radius, radius)
    ip = usable[ip]
    cost = sad(previous.descriptors, current.descriptors, ip, ic)
    return best_of(ip, ic, cost, len(previous)), best_of(ic, ip, cost, len(current))


def close_circle(lc_to_rc: Index, rc_to_rp: Index, rp_to_lp: Index, lp_to_lc: Index) -> npt.NDArray[np.intp]:
    """Quadruples (last-left, last-right, previous-right, previous-left) whose circle closes.

    Each argument maps a feature index of one image to its best match in the next image of the
    circle (-1 = none). Returns an M x 4 index array.
    """
    start = np.arange(len(lc_to_rc))
    rc = lc_to_rc
    ok = rc >= 0
    rp = np.where(ok, rc_to_rp[np.where(ok, rc, 0)], _NONE) if len(rc_to_rp) else np.full_like(rc, _NONE)
    ok &= rp >= 0
    lp = np.where(ok, rp_to_lp[np.where(ok, rp, 0)], _NONE) if len(rp_to_lp) else np.full_like(rc, _NONE)
    ok &= lp >= 0
    back = np.where(ok, lp_to_lc[np.where(ok, lp, 0)], _NONE) if len(lp_to_lc) else np.full_like(rc, _NONE)
    ok &= back == start
    return np.stack([start[ok], rc[ok], rp[ok], lp[ok]], axis=1)
