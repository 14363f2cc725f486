"""True velocities of real data: the least-squares slope of each object's labelled positions.

Hand or lidar labels jitter by 0.1-0.5 m/s from frame to frame, which would put a parked car
above the 0.3 m/s stationary limit; a straight-line fit over +-5 frames removes that jitter while
following real accelerations. Synthetic scenes know their velocities exactly and keep them.
Fitting from positions (not from whatever velocity an importer stored) makes the figure the same
however the recording was made.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping

import numpy as np

from common.messages import GroundTruthObjects

#: frames on each side of a frame used for the fit.
HALF_WINDOW: int = 5


def _times_s(truth: Mapping[int, GroundTruthObjects], frame_rate_hz: float) -> dict[int, float]:
    """Capture times in seconds; frame numbers over the frame rate when stamps do not advance."""
    stamps = {fid: msg.stamp_ns / 1e9 for fid, msg in truth.items()}
    ordered = [stamps[f] for f in sorted(stamps)]
    if len(ordered) > 1 and all(b > a for a, b in itertools.pairwise(ordered)):
        return stamps
    return {fid: fid / frame_rate_hz for fid in truth}


def fit_velocities(
    truth: Mapping[int, GroundTruthObjects], frame_rate_hz: float = 10.0, half_window: int = HALF_WINDOW
) -> int:
    """Replace each object's velocity by the slope of its world position over +-``half_window``.

    Objects seen in one frame only keep their stored velocity. Returns how many were refitted.
    """
    times = _times_s(truth, frame_rate_hz)
    tracks: dict[int, dict[int, np.ndarray]] = {}
    for fid, msg in truth.items():
        for obj in msg.objects:
            tracks.setdefault(obj.id, {})[fid] = np.asarray(obj.center, dtype=np.float64)
    refitted = 0
    for fid, msg in truth.items():
        for obj in msg.objects:
            near = [f for f in tracks[obj.id] if abs(f - fid) <= half_window]
            if len(near) < 2:
                continue
            t = np.array([times[f] for f in near])
            positions = np.array([tracks[obj.id][f] for f in near])
            t_centred = t - t.mean()
            denominator = float(t_centred @ t_centred)
            if denominator <= 0.0:
                continue
            obj.velocity = (t_centred @ (positions - positions.mean(axis=0))) / denominator
            refitted += 1
    return refitted
