"""Two moving tracks on one walker: the wider one is not called moving.

A walker's smear at 15-25 m can come apart into two clusters, his body and a piece of smear beside
him (towards the wall, say), and both become tracks that move at his pace. The evaluation matches
one of them to him and counts the other as a false moving frame. On held-out synthetic urban
(seeds 7-10, session 54) such twins made 12 of the 27 false moving frames: urban-s10's walker 46
had a second track 0.4-0.7 m beside him at 1.6-1.9 m/s for 9 frames, 1.2-2.4 m wide across the
line of sight where he was 0.4-0.7 m; walker 45 one 0.2-0.4 m beside him, as narrow as he, for 3.

Two people walking side by side are each as narrow as a person, and their centres lie half a
metre apart or more. So where two moving tracked tracks move within ``mps`` of one velocity, one
loses its moving label (it keeps its track) when their boxes overlap by ``overlap_m`` and it is
``wide_m`` wide across the line of sight while the other is narrower, or, whatever their widths,
when their centres lie within ``near_m``: then the wider one loses it. Taking the wider of any
two whose boxes touch cost crossing 14-29 true frames on each set of seeds: people crossing in
groups (docs/results/tracking.md, "Session 54").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from services.tracker.track import TRACKED, TrackTable

NDArray = npt.NDArray[Any]


@dataclass(frozen=True)
class Twins:
    """When a moving track is a twin of another (config ``tracker.twin_*``)."""

    overlap_m: float = -1.0  # boxes (x, y) overlapping by this much in x and in y; < 0: never
    mps: float = 0.75  # ... and velocities (x, y) this near
    wide_m: float = 1.5  # ... the one this wide across the line of sight or wider, the other narrower
    near_m: float = -1.0  # or centres (x, y) this near, whatever their widths (the wider one loses); < 0: never


NO_TWINS = Twins()  # both tests off


@numba.njit(cache=True)
def _losers(lo: NDArray, hi: NDArray, centre: NDArray, velocity: NDArray, width: NDArray, overlap_m: float,
            mps: float, wide_m: float, near_m: float) -> NDArray:
    """Pairwise over the candidates: which lose their label (a loop: 50 moving tracks took 0.3 ms in numpy)."""
    n = lo.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        for j in range(i + 1, n):
            if np.hypot(velocity[i, 0] - velocity[j, 0], velocity[i, 1] - velocity[j, 1]) > mps:
                continue
            wider, other = (i, j) if width[i] > width[j] else (j, i)  # of two alike, the later
            if np.hypot(centre[i, 0] - centre[j, 0], centre[i, 1] - centre[j, 1]) <= near_m:
                out[wider] = True
                continue
            if overlap_m < 0.0 or not (width[wider] >= wide_m and width[other] < wide_m):
                continue
            ox = min(hi[i, 0] - lo[j, 0], hi[j, 0] - lo[i, 0])
            oy = min(hi[i, 1] - lo[j, 1], hi[j, 1] - lo[i, 1])
            if min(ox, oy) >= overlap_m:
                out[wider] = True
    return out


def wider_twins(t: TrackTable, rule: Twins) -> NDArray:
    """Which moving tracked tracks lose their label to a narrower moving twin (see the module text)."""
    out = np.zeros(len(t), dtype=bool)
    if rule.overlap_m < 0.0 and rule.near_m < 0.0:
        return out
    cand = np.flatnonzero(t.moving & (t.queue == TRACKED))
    if cand.size < 2:
        return out
    centre = t.x[cand, 0:2] + t.offset[cand, 0:2]  # where the tracks are now, as reported
    shift = centre - t.centroid[cand, 0:2]
    lo, hi = t.bbox_min[cand, 0:2] + shift, t.bbox_max[cand, 0:2] + shift
    width = np.where(np.isfinite(t.across[cand]), t.across[cand], (hi - lo).min(axis=1))
    out[cand] = _losers(lo, hi, centre, np.ascontiguousarray(t.x[cand, 3:5]), width, rule.overlap_m, rule.mps,
                        rule.wide_m, rule.near_m)
    return out
