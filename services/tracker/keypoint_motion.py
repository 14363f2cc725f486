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
        seen = np.isin(self.ids, ids)
        kept = ~seen & (self.missed < MAX_GAP)
        all_ids = np.concatenate([ids, self.ids[kept]])
        order = np.argsort(all_ids, kind="stable")
        m, k = len(ids), int(kept.sum())
        xy, t = np.zeros((m + k, HISTORY, 2)), np.zeros((m + k, HISTORY))
        n, missed = np.ones(m + k, dtype=np.int64), np.zeros(m + k, dtype=np.int64)
        now, doubt = np.full((m + k, 3), np.nan), np.concatenate([np.asarray(std, dtype=np.float64), self.std[kept]])
        at = np.searchsorted(self.ids, ids)  # self.ids is sorted
        known = np.zeros(m, dtype=bool)
        if len(self.ids):
            at = np.minimum(at, len(self.ids) - 1)
            known = self.ids[at] == ids
        rows = np.flatnonzero(known)
        xy[rows, :-1], t[rows, :-1] = self.xy[at[known], 1:], self.t[at[known], 1:]
        n[rows] = np.minimum(self.n[at[known]] + 1, HISTORY)
        xy[:m, -1], t[:m, -1], now[:m] = xyz[:, 0:2], clock, xyz
        xy[m:], t[m:], n[m:], missed[m:] = self.xy[kept], self.t[kept], self.n[kept], self.missed[kept] + 1
        self.ids, self.xy, self.t, self.n = all_ids[order], xy[order], t[order], n[order]
        self.missed, self.now, self.std = missed[order], now[order], doubt[order]

    def velocities(self, min_samples: int) -> tuple[NDArray, NDArray, NDArray]:
        """Which corners were seen this frame with ``min_samples`` positions or more, their velocities (m, 2)
        and the doubt (m,) their range's brings to them."""
        ready = (self.n >= max(min_samples, 2)) & (self.missed == 0)
        xy, t, n = self.xy[ready], self.t[ready], self.n[ready]
        w = (np.arange(HISTORY)[None, :] >= HISTORY - n[:, None]).astype(np.float64)  # the last n slots
        t_mean = (w * t).sum(axis=1) / n
        dt = (t - t_mean[:, None]) * w
        xy_mean = (w[:, :, None] * xy).sum(axis=1) / n[:, None]
        denom = (dt * dt).sum(axis=1)
        slope = (dt[:, :, None] * (xy - xy_mean[:, None, :])).sum(axis=1) / np.maximum(denom, 1e-12)[:, None]
        return ready, slope, self.std[ready] / np.sqrt(np.maximum(denom, 1e-12))


def corner_velocity(history: CornerHistory, pieces: list[Cluster], edge: float, min_samples: int) -> CornerVelocity:
    """Each piece's corners (those in its voxels this frame) and their median velocity."""
    n = len(pieces)
    out = CornerVelocity(np.zeros((n, 2)), np.full(n, np.inf), np.zeros(n, dtype=np.int64))
    ready, velocity, doubt = history.velocities(min_samples)
    if n == 0 or not ready.any():
        return out
    keys = [pack_cells(np.asarray(p.voxels).reshape(-1, 3)) for p in pieces]
    owner = np.repeat(np.arange(n), [len(k) for k in keys])
    all_keys = np.concatenate(keys)
    order = np.argsort(all_keys, kind="stable")
    all_keys, owner = all_keys[order], owner[order]
    corner_keys = pack_cells(np.floor(history.now[ready] / edge))
    at = np.minimum(np.searchsorted(all_keys, corner_keys), len(all_keys) - 1)
    on = all_keys[at] == corner_keys
    whose, velocity, doubt = owner[at[on]], velocity[on], doubt[on]
    for j in np.unique(whose):
        mine = whose == j
        v, m = velocity[mine], int(mine.sum())
        median = np.median(v, axis=0)
        spread = MAD_SIGMA * np.median(np.linalg.norm(v - median, axis=1)) / np.sqrt(m)
        stereo = float(np.median(doubt[mine])) * np.sqrt(SHARED + (1.0 - SHARED) / m)
        out.velocity[j], out.count[j], out.sigma[j] = median, m, max(spread, stereo)
    return out


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
