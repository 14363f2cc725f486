"""A piece's corners' velocity carried from the middle of their lines to this frame.

common/corner_motion.py fits each followed corner's line through its last positions; this carries a
brisk piece's lines forward by its corners' median acceleration (``CornerLead``), before their
medians are taken.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from common.fast_median import MAD_SIGMA, median

NDArray = npt.NDArray[Any]


@dataclass(frozen=True)
class CornerLead:
    """When a piece's corners' velocity is carried from the middle of their lines to this frame
    (config ``tracker.corner_lead_*``): by the median acceleration of a parabola through each one's
    positions, where that median is ``sigmas`` of its scatter sure, on a piece whose corners already
    read ``min_mps`` or more, from the corners with ``samples`` positions or more.

    A line through 0.8 s of positions gives the velocity 0.35 s ago. A car changing lane
    accelerates sideways 1 m/s^2 for a second and more, and every urban run's lead car was read
    0.6 m/s short sideways to the end of its lane change, the largest single speed error on every
    run (docs/results/tracking.md, "Session 66"). Only a piece already moving briskly is carried: on
    slower ones (a walker setting off, a standing post's jittering corners) the parabolas' scatter
    passed for acceleration and added false moving frames.
    """

    sigmas: float = 0.0  # 0: never carried
    min_mps: float = 0.0
    samples: int = 8  # positions a corner needs (corner_motion.HISTORY keeps 8)


NO_LEAD = CornerLead()
#: fewest corners with ``CornerLead.samples`` positions whose median acceleration a piece is carried by.
LEAD_MIN_CORNERS: int = 4


@numba.njit(cache=True)
def carry(
    slope: NDArray, members: NDArray, start: NDArray, xy: NDArray, t: NDArray, n: NDArray, w: NDArray,
    sigmas: float, min_mps: float, samples: int,
) -> None:  # fmt: skip
    """Each piece's lines (``slope``, by member) carried to their last position's time by the median of
    its corners' accelerations, axis by axis, where it is ``sigmas`` of its scatter (MAD) sure, on a
    piece whose median velocity is ``min_mps`` or more (``CornerLead``)."""
    m = members.shape[0]
    acc, lead, which = np.empty((m, 2)), np.empty(m), np.empty(m, np.int64)
    scratch, values = np.empty(max(1, m)), np.empty(max(1, m))
    for p in range(start.shape[0] - 1):
        a, b = start[p], start[p + 1]
        if b - a < LEAD_MIN_CORNERS:
            continue
        if np.hypot(median(slope[a:b, 0], scratch), median(slope[a:b, 1], scratch)) < min_mps:
            continue
        k = 0
        for i in range(a, b):
            c = members[i]
            if n[c] >= samples:
                acc[k, 0], acc[k, 1], lead[k] = _acceleration(xy, t, n[c], w[c], c)
                which[k] = i
                k += 1
        if k < LEAD_MIN_CORNERS:
            continue
        for axis in range(2):
            middle = median(acc[:k, axis], scratch)
            for q in range(k):
                values[q] = abs(acc[q, axis] - middle)
            if abs(middle) > sigmas * MAD_SIGMA * median(values[:k], scratch) / np.sqrt(k):
                for q in range(k):
                    slope[which[q], axis] += middle * lead[q]


@numba.njit(cache=True)
def _acceleration(xy: NDArray, t: NDArray, n: int, w: int, r: int) -> tuple[float, float, float]:
    """Row ``r``'s acceleration (x, y) from the parabola through its last ``n`` positions, and how far
    (s) the velocity at its last position lies past its line's: the parabola's slope there is the
    line's plus acceleration times that. The parabola's square term is taken orthogonal to the line's
    terms, so the line (corner_motion's ``_line``) stays as fitted."""
    ring = t.shape[1]
    t_mean = 0.0
    for q in range(w - n, w):
        t_mean += t[r, q % ring]
    t_mean /= n
    s2 = s3 = 0.0
    for q in range(w - n, w):
        d = t[r, q % ring] - t_mean
        s2 += d * d
        s3 += d * d * d
    s2 = max(s2, 1e-12)
    mean2, skew = s2 / n, s3 / s2  # the square term less its projections on the constant and the line
    ss = sx = sy = 0.0
    for q in range(w - n, w):
        k = q % ring
        d = t[r, k] - t_mean
        e = d * d - mean2 - skew * d
        ss += e * e
        sx += e * xy[r, k, 0]
        sy += e * xy[r, k, 1]
    ss = max(ss, 1e-12)
    last = t[r, (w - 1) % ring] - t_mean
    return 2.0 * sx / ss, 2.0 * sy / ss, last - 0.5 * skew
