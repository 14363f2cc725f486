"""A track's velocity from the corners on it that the stereo stage follows (stereo_depth/keypoints.py).

The filter and the faces' window measure a cluster, and a cluster is whatever the mapper joined
this frame: a walker passing a bin shares one with it, a smear's fringe grows and shrinks with
range. A corner followed in the image stays on the surface it was found on: a track's corners
(those in its cluster's voxels) and their median velocity and its doubt come from
common/corner_motion.py. The doubt is the range's, along the line of sight. Across it a corner's
place is known to a fraction of a pixel, millimetres at 20 m: a walker setting off across the road
15 m ahead, his four to six corners read 0.7-0.9 m/s with a sigma of 0.27-0.74 m/s, and of
0.06-0.14 m/s across the line of sight (synthetic crossing-s8, walker 7). So each track also gets
the median of its corners' speeds across the line of sight, with a doubt of its own (their
scatter, or ``CornerRule.across_std_m`` through the line's fit); its size less that doubt is a
lower bound on the track's speed too (labelling.py; docs/results/tracking.md, "Session 43").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from common.config import TrackerConfig
from common.corner_lead import NO_LEAD, CornerLead
from common.corner_motion import CornerHistory, corner_velocity
from services.tracker import kalman
from services.tracker.anchor import Footprint
from services.tracker.left_behind import restart_from_rest
from services.tracker.track import GHOST, TrackTable

NDArray = npt.NDArray[Any]


@dataclass(frozen=True)
class CornerMover:
    """When a group of a track's corners moving across the line of sight turns it moving, though the
    rest stand (config ``tracker.corner_mover_*``; common/corner_motion.py's ``_movers``)."""

    count: int  # corners in the group
    mps: float  # their median speed across the line of sight
    from_mps: float  # each one's at least
    tol_mps: float  # ... and within this of the group's
    width_m: float  # the group's width across the line of sight, at most
    filter_mps: float  # the track's filter's speed, over


@dataclass(frozen=True)
class CornerRule:
    """When the corners on a track label it (config ``tracker.corner_*``; labelling.py)."""

    samples: int = 0  # frames a corner must have been followed for its velocity; 0: corners unused
    min_count: int = 0  # corners a track needs for their opinion
    on_mps: float = 0.0  # the speed they must be sure of to turn it moving
    sigma_k: float = 0.0  # ... sure by this many of their sigmas
    still_mps: float = 0.0  # sure (as above) that it is slower than this, they keep it from turning moving; 0: off
    update_gate: float = 0.0  # their velocity corrects the filter's within this squared innovation (2-D); 0: off
    update_floor_mps: float = 0.0  # ... its doubt never taken below this
    confirm_count: int = 0  # this many or more, sure of a speed, may stand in for the faces' window; 0: never
    blend_count: int = 0  # this many or more are blended into a moving track's reported velocity; 0: min_count
    across_std_m: float = 0.0  # a corner's position doubt across the line of sight (m); 0: not judged across
    restart_count: int = 0  # this many or more, beyond a revived standing ghost's filter's gate, restart it; 0: never
    lead: CornerLead = NO_LEAD  # when their velocity is carried to this frame by their acceleration
    mover: CornerMover | None = None  # when a group of them moving across the line of sight turns it moving


NO_CORNERS = CornerRule()


def corner_rule(t: TrackerConfig) -> CornerRule:
    """The corners' rule as the tracker's settings give it (``tracker.corner_*``)."""
    return CornerRule(
        t.corner_samples, t.corner_min_count, t.corner_on_mps, t.corner_sigma_k, t.corner_still_mps,
        t.corner_update_gate, t.corner_update_floor_mps, t.corner_confirm_count, t.corner_blend_count,
        t.corner_across_std_m, t.corner_restart_count,
        CornerLead(t.corner_lead_sigmas, t.corner_lead_min_mps, t.corner_lead_samples),
        CornerMover(
            t.corner_mover_count, t.corner_mover_mps, t.corner_mover_from_mps, t.corner_mover_tol_mps,
            t.corner_mover_width_m, t.corner_mover_filter_mps,
        ) if t.corner_mover_count > 0 else None,
    )  # fmt: skip


def track_corners(
    t: TrackTable,
    history: CornerHistory,
    rule: CornerRule,
    rows: NDArray,
    cols: NDArray,
    stacked: Footprint,
    edge: float,
    eye: NDArray,
) -> None:
    """Each track's corners this frame, from the cluster it was paired with (track ``rows``, observation
    ``cols`` of ``stacked``): their median velocity, its doubt and their number, their speed across
    the line of sight from ``eye``, and (``rule.mover``) their largest group moving across it; none on
    an unseen track."""
    t.corner_count[:] = 0
    t.corner_mover[:] = 0.0
    if rule.samples <= 0 or len(rows) == 0:
        return
    slot = np.full(len(stacked.counts), -1, dtype=np.int64)
    slot[cols] = np.arange(len(cols))
    c = corner_velocity(
        history, stacked.voxels, stacked.counts, slot, len(rows), edge, rule.samples, eye, rule.across_std_m,
        rule.lead, *((rule.mover.from_mps, rule.mover.tol_mps) if rule.mover is not None else (0.0, 0.0)),
    )  # fmt: skip
    t.corner_velocity[rows], t.corner_sigma[rows], t.corner_count[rows] = c.velocity, c.sigma, c.count
    t.corner_across[rows], t.corner_across_sigma[rows] = c.across, c.across_sigma
    if c.mover is not None:
        t.corner_mover[rows] = c.mover


def correct_by_corners(t: TrackTable, rule: CornerRule) -> None:
    """The filter corrected with the median velocity of the corners on each track, where it holds
    ``rule.min_count`` of them or more, as a measurement as doubtful as they are (never below
    ``rule.update_floor_mps``), unless it lies beyond ``rule.update_gate`` of what the filter expects.

    Until session 42 the corners only labelled a track and were blended into what it reports; a
    track restarted from rest, or one whose cluster slid, read its speed from its faces alone for
    frames while five corners on it said how it moved. The gate leaves out corners that see the
    background drift past a pole's edges, and a neighbour's that outvote a track's own
    (docs/results/tracking.md, "Session 42").
    """
    if rule.update_gate <= 0.0 or rule.samples <= 0:
        return
    rows = np.flatnonzero((t.corner_count >= max(rule.min_count, 1)) & np.isfinite(t.corner_sigma))
    std = np.maximum(t.corner_sigma[rows], rule.update_floor_mps)
    kalman.correct_velocity(t.x, t.p, rows, t.corner_velocity[rows], std, rule.update_gate)


def beyond_gate(t: TrackTable, rule: CornerRule, rows: NDArray) -> NDArray:
    """Which of the tracks ``rows`` hold ``rule.restart_count`` corners or more whose median velocity
    lies beyond ``rule.update_gate`` (2-D squared innovation) of what the filter expects.

    ``correct_by_corners`` leaves such corners out, rightly for a track it has followed: they see a
    neighbour or the background. A ghost found again is another matter: a standing one's velocity
    was never confirmed, and coasting on it the ghost may have drifted onto a walker, whose corners
    then say a pace the filter rejects for frames (synthetic urban-s7: a smear blob's two centroid
    steps read as 3 m/s, its ghost drifted 1.5 m onto walker 49 and reported him at (-0.9, 0.7) m/s
    against his (1.9, 0.2) while 12-20 corners on him read 1.5-1.9; docs/results/tracking.md,
    "Session 51"). Such a track starts again from rest (``restart_revived``) and the corners correct it.
    """
    rows = np.asarray(rows, dtype=np.int64)
    out = np.zeros(len(rows), dtype=bool)
    if rule.restart_count <= 0 or rule.update_gate <= 0.0 or rule.samples <= 0:
        return out
    held = np.flatnonzero((t.corner_count[rows] >= rule.restart_count) & np.isfinite(t.corner_sigma[rows]))
    k = rows[held]
    std = np.maximum(t.corner_sigma[k], rule.update_floor_mps)
    s = t.p[k, 3:5, 3:5] + (std * std)[:, None, None] * np.eye(2)
    y = t.corner_velocity[k] - t.x[k, 3:5]
    out[held] = np.einsum("ni,ni->n", y, np.linalg.solve(s, y[:, :, None])[:, :, 0]) > rule.update_gate
    return out


def restart_revived(t: TrackTable, rule: CornerRule, rows: NDArray, velocity_var: NDArray) -> int:
    """Standing ghosts among the tracks seen this frame (``rows``) whose corners' pace the filter
    rejects (``beyond_gate``) start again from rest, before the corners correct the filter; how many."""
    if rule.restart_count <= 0:
        return 0
    revived = rows[(t.queue[rows] == GHOST) & ~t.moving[rows]]
    if len(revived) == 0:
        return 0
    return restart_from_rest(t, revived[beyond_gate(t, rule, revived)], velocity_var)


def blend_corners(t: TrackTable, rule: CornerRule, velocity: NDArray, velocity_cov: NDArray) -> None:
    """A moving track's reported horizontal velocity blended with its corners', each by the inverse of
    its variance, where at least ``rule.blend_count`` corners are on it; ``velocity_cov`` shrinks alike.

    The corners turn walkers moving whose filter still doubts their speed (labelling.py); what it
    reports for them is that doubted speed, unless the corners' is blended in.
    """
    held = t.moving & (t.corner_count >= max(rule.blend_count or rule.min_count, 1)) & np.isfinite(t.corner_sigma)
    if rule.samples <= 0 or not held.any():
        return
    reported_var = np.maximum(0.5 * (velocity_cov[:, 0, 0] + velocity_cov[:, 1, 1]), 1e-12)
    sigma = np.where(held, t.corner_sigma, 1.0)
    w = np.where(held, reported_var / (reported_var + sigma * sigma), 0.0)  # the corners' weight
    velocity[:, 0:2] += w[:, None] * (t.corner_velocity - velocity[:, 0:2])
    velocity_cov[:, 0:2, 0:2] *= (1.0 - w)[:, None, None]
