"""Two moving tracks on one walker: the wider one is not called moving.

A walker's smear at 15-25 m can come apart into two clusters, his body and a piece of smear beside
him (on the wall's side, or where his shadow falls), and both become tracks that move at his pace.
The evaluation matches one of them to him and counts the other as a false moving frame: on
held-out synthetic urban (seeds 7-10) that was most of them in session 54 (urban-s10, walker 46:
two tracks 0.4-0.7 m apart at 1.6-1.9 m/s for 8 frames). Two people walking side by side are
each as narrow as a person across the line of sight; the piece of smear is wider (1.2-2.4 m). So
where two moving tracks' boxes overlap by ``overlap_m`` and their velocities within
``mps``, the one wider across the line of sight keeps its track but not its moving label.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from services.tracker.track import TRACKED, TrackTable

NDArray = npt.NDArray[Any]


@dataclass(frozen=True)
class Twins:
    """When a moving track is a twin of another (config ``tracker.twin_overlap_m``, ``tracker.twin_mps``)."""

    overlap_m: float = -1.0  # boxes (x, y) overlapping by this much in x and in y; < 0: off
    mps: float = 0.5  # ... and velocities (x, y) this near
    wide_m: float = 1.0  # ... the one this wide across the line of sight or wider, the other narrower
    near_m: float = -1.0  # or centres (x, y) this near, whatever their widths (the wider one loses); < 0: off


NO_TWINS = Twins()


def wider_twins(t: TrackTable, rule: Twins) -> NDArray:
    """Which moving tracked tracks lose their label to a narrower moving twin (see the module text)."""
    out = np.zeros(len(t), dtype=bool)
    if rule.overlap_m < 0.0 and rule.near_m < 0.0:
        return out
    cand = np.flatnonzero(t.moving & (t.queue == TRACKED))
    if cand.size < 2:
        return out
    shift = (t.x[cand, 0:2] + t.offset[cand, 0:2]) - t.centroid[cand, 0:2]  # the boxes where the tracks are now
    lo, hi = t.bbox_min[cand, 0:2] + shift, t.bbox_max[cand, 0:2] + shift
    overlap = np.minimum(hi[:, None, :] - lo[None, :, :], hi[None, :, :] - lo[:, None, :]).min(axis=2)
    dv = np.linalg.norm(t.x[cand, None, 3:5] - t.x[None, cand, 3:5], axis=2)
    extent = hi - lo
    width = np.where(np.isfinite(t.across[cand]), t.across[cand], extent.min(axis=1))
    centre = t.x[cand, 0:2] + t.offset[cand, 0:2]
    near = np.linalg.norm(centre[:, None, :] - centre[None, :, :], axis=2) <= rule.near_m
    wide = (width[:, None] >= rule.wide_m) & (width[None, :] < rule.wide_m)
    wider = (width[:, None] > width[None, :]) | ((width[:, None] == width[None, :]) & (cand[:, None] > cand[None, :]))
    lose = (((overlap >= rule.overlap_m) & wide) if rule.overlap_m >= 0.0 else False) | (near & wider)
    lose &= dv <= rule.mps
    np.fill_diagonal(lose, False)
    out[cand] = lose.any(axis=1)
    return out
