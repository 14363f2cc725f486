"""A cluster further from its track's prediction than the filter allows: a jump, not motion.

Such a cluster is one that changed shape (split, merged, another face in view). The track is
re-anchored on it: the position is taken as measured, the velocity kept, since the step says
nothing about how the object moves, but doubted by ``speed_var`` more. Without that doubt the
kept velocity also kept its settled covariance, and a track that had slid onto a slower object
was hardly corrected by the clusters after the jump (synthetic urban-s8: 8-10 m/s carried on a
walker at 1.7 for sixteen frames, re-anchored every second or third; docs/results/tracking.md,
"Session 33").

A track younger than ``young_frames`` has no settled shape, and a cluster that far off is more
often the next object along a row (urban-s8's track 25 went wall -> pole -> bin -> walker, each
at the range the last had as the vehicle closed in): ``unpair_young`` leaves it unpaired, so the
young track misses a frame and the cluster starts its own. Off by default: on KITTI tracking 0001
the clusters so freed started phantom tracks on far structures.

The other way round, a jump can be too large for association to pair at all: a track whose
position has settled allows a few decimetres, and a cyclist's cluster 0.8 m ahead of its lagging
track found no pair, so a new track was born on it at rest while the old one went on as a ghost
at his 6 m/s beside it (synthetic urban-s69, cyclist 182: the new track read him 5.1 and 2.5
m/s slow in its first two moving frames). ``retake`` gives a track labelled moving, left unpaired,
the nearest cluster nobody took within ``retake_m`` of where it was predicted: it re-anchors there
and keeps its speed (docs/results/tracking.md, "Session 61").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from services.tracker import kalman
from services.tracker.association import greedy_pairs
from services.tracker.track import ACCEPTANCE, TrackTable

NDArray = npt.NDArray[Any]


@dataclass(frozen=True)
class Jumps:
    """The jump's limit and what follows one (config: ``tracker.jump_*``, ``young_jump_frames``)."""

    nis: float  # squared Mahalanobis distance over 3 dimensions (chi2 95 %: 7.8)
    speed_var: float = 0.0  # added to the kept horizontal velocity's variance (m^2/s^2)
    young_frames: int = 0  # tracks younger than this are not paired with a jump; 0 = off
    retake_m: float = 0.0  # a moving track left unpaired takes a cluster nobody took this near (m); 0 = off
    retake_misses: int = 0  # ... if unseen for at most this many frames before this one

    def of(self, nis: NDArray) -> NDArray:
        """Which innovations (normalised per dimension, 3 of them) re-anchor rather than correct."""
        return nis * 3.0 > self.nis

    def re_anchor(
        self, jump: NDArray, x: NDArray, p: NDArray, x_before: NDArray, p_before: NDArray, point: NDArray, r: NDArray
    ) -> None:
        """Overwrite the corrected states ``x``, ``p`` where ``jump``: measured position, kept velocity."""
        x[jump, 0:3] = point[jump]
        x[jump, 3:6] = x_before[jump, 3:6]
        p[jump] = p_before[jump]
        p[jump, 0:3, 0:3] = r[jump]
        p[jump, 0:3, 3:6] = 0.0
        p[jump, 3:6, 0:3] = 0.0
        p[jump, 3, 3] += self.speed_var
        p[jump, 4, 4] += self.speed_var

    def unpair_young(
        self, rows: NDArray, cols: NDArray, tracks: TrackTable, point: NDArray, r: NDArray
    ) -> tuple[NDArray, NDArray]:
        """The pairs (track rows, cluster columns) less the young tracks' jumps.

        ``point`` and ``r`` are every cluster's followed point and covariance; ``r`` is scaled by
        the track's adaptive noise, as in the correction. The innovation is the prediction's,
        before the correction turns a track to another face.
        """
        if self.young_frames <= 0 or len(rows) == 0:
            return rows, cols
        young = tracks.age[rows] < self.young_frames
        if not young.any():
            return rows, cols
        scale = np.maximum(tracks.nis[rows], 1.0)[:, None, None]
        nis = kalman.normalised_innovation(tracks.x[rows], tracks.p[rows], point[cols], r[cols] * scale)
        keep = ~(young & self.of(nis))
        return rows[keep], cols[keep]

    def retake(
        self, rows: NDArray, cols: NDArray, tracks: TrackTable, centroid: NDArray
    ) -> tuple[NDArray, NDArray]:
        """The pairs (track rows, cluster columns) and, for each track labelled moving that they
        leave out (tracked, or a ghost unseen ``retake_misses`` frames at most), the nearest cluster
        they leave out whose ``centroid`` lies within ``retake_m`` of the track's predicted one (x, y)."""
        if self.retake_m <= 0.0 or len(cols) == len(centroid) or len(rows) == len(tracks):
            return rows, cols  # off, or nothing left over on one side
        unpaired = np.ones(len(tracks), dtype=bool)
        unpaired[rows] = False
        recent = (tracks.queue != ACCEPTANCE) & (tracks.misses <= self.retake_misses)
        lost = np.flatnonzero(unpaired & tracks.moving & recent)
        if len(lost) == 0:
            return rows, cols
        left = np.ones(len(centroid), dtype=bool)
        left[cols] = False
        left = np.flatnonzero(left)
        predicted = tracks.x[lost, 0:2] + tracks.offset[lost, 0:2]
        apart = np.hypot(
            predicted[:, None, 0] - centroid[None, left, 0], predicted[:, None, 1] - centroid[None, left, 1]
        )
        more_rows, more_cols = greedy_pairs(apart, self.retake_m)
        return np.concatenate([rows, lost[more_rows]]), np.concatenate([cols, left[more_cols]])
