"""What a re-observed cluster says about how far its object moved.

A cluster's centroid is the centre of what is visible, not of the object: driving past a parked
car, its side comes into view (the centroid slides forward) and then its back leaves the volume
of interest (the centroid slides again) while the car stands still. Fed to the filter, those
slides look like metres per second. A rigid object moves all of its box at once, though, so when
the box grew or shrank along an axis by more than a tolerance, the displacement along that axis
is taken from whichever of centroid, low face or high face moved most like the prediction; the
face that stayed put wins for a parked car, and for a moving car all three agree. Along axes
whose extent held, the centroid's displacement is used: it averages the most voxels.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

NDArray = npt.NDArray[Any]


def displacement(
    prev_centroid: NDArray,
    prev_min: NDArray,
    prev_max: NDArray,
    centroid: NDArray,
    bbox_min: NDArray,
    bbox_max: NDArray,
    predicted: NDArray,
    tolerance: float,
) -> NDArray:
    """Per-axis displacement (n, 3) of ``n`` clusters since their track's last cluster.

    ``predicted`` is the filter's predicted displacement over the same time; ``tolerance`` the
    change of extent (metres) below which the box counts as unchanged.
    """
    candidates = np.stack([centroid - prev_centroid, bbox_min - prev_min, bbox_max - prev_max])
    changed = np.abs((bbox_max - bbox_min) - (prev_max - prev_min)) > tolerance
    best = np.argmin(np.abs(candidates - predicted[None]), axis=0)
    chosen = np.take_along_axis(candidates, best[None], axis=0)[0]
    return np.where(changed, chosen, candidates[0])
