"""The median of a short array, compiled, without a sort or an allocation.

The tracker takes medians of a few dozen values many times a frame (each piece's corners, their
velocities, doubts and accelerations: common/corner_motion.py, corner_lead.py).
"""

from __future__ import annotations

from typing import Any

import numba
import numpy.typing as npt

NDArray = npt.NDArray[Any]

#: scale of the median absolute deviation to a normal distribution's sigma.
MAD_SIGMA: float = 1.4826


@numba.njit(cache=True)
def median(values: NDArray, scratch: NDArray) -> float:
    """np.median of ``values``, selected in ``scratch`` (at least as long) without a sort: each np.median
    call allocates, and the insertion sort this replaced fell back to it past 64 values, where a car's
    side in the tracker's benchmark holds 130 corners since session 48."""
    m = values.shape[0]
    for i in range(m):
        scratch[i] = values[i]
    h = m // 2
    upper = _select(scratch, m, h)
    if m % 2:
        return upper
    lower = scratch[0]  # the largest of the ``h`` values the selection left below ``upper``
    for i in range(1, h):
        lower = max(lower, scratch[i])
    return 0.5 * (lower + upper)


@numba.njit(cache=True)
def _select(a: NDArray, m: int, k: int) -> float:
    """The ``k``-th smallest of ``a[:m]``, with every smaller value left before slot ``k``.

    Each round moves the values below a pivot (the median of three) to the front and those equal to
    it next, by swaps whose outcome is added, not branched on: over the tracker benchmark's frames
    ``_piece_velocities`` took 0.48 ms a frame with it against 0.57 with Hoare's selection, whose
    branches depend on the values. The pass for equal values keeps runs of them (corners followed alike share their
    doubts) from taking a round each.
    """
    lo, hi = 0, m - 1
    while lo < hi:
        x, y, z = a[lo], a[(lo + hi) >> 1], a[hi]
        pivot = max(min(x, y), min(max(x, y), z))
        below = lo
        for i in range(lo, hi + 1):
            v = a[i]
            a[i] = a[below]
            a[below] = v
            below += v < pivot
        if k < below:
            hi = below - 1
            continue
        equal = below
        for i in range(below, hi + 1):
            v = a[i]
            a[i] = a[equal]
            a[equal] = v
            equal += v <= pivot
        if k < equal or equal == lo:  # (equal == lo only for a NaN pivot: no round would end)
            return pivot
        lo = equal
    return a[k]
