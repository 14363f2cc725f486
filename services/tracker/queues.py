"""The paper's three queues: acceptance, tracked and ghost, and the moves between them.

- acceptance: a new cluster; promoted to tracked once seen ``accept_frames`` frames (its birth
  frame included), discarded once unseen for more than ``accept_misses`` frames in a row (the
  paper: 0, the first frame it is not seen);
- tracked: seen this frame; becomes a ghost the first frame it is not, unless it coasts (below);
- ghost: not seen for ``misses`` frames; back to tracked when seen again, discarded once unseen
  for more than ``ghost_frames`` frames.
Frames lost in a gap of the input count as frames unseen, so a long gap retires ghosts.

A walker's track coasts, tracked though unseen, while its cluster has merged into a neighbour's:
walkers crossing two or three abreast, a step apart in range, are joined by stereo smear into one
cluster for a few frames, which one track takes; the others turned ghosts where the walkers were
(synthetic crossing seed 8: 21 walker-frames, the ghosts mostly within 0.3 m of their walkers),
and the walkers went unreported. A track coasts when its reported position lies inside the box of
a tracked object seen this frame, for at most ``Coasting.frames`` frames. Only an upright track
does (a person or a pole): letting any shape coast added false moving frames and a parked track
called moving. Only one old enough: a young track's velocity is still a guess, and coasting
reports it for longer. Only one at a walker's or a cyclist's speed: a car's rear is upright too
(tall, and thin in range), and a car at 7 m/s coasted 2 m past where it was last seen
(docs/results/tracking.md, "Session 23").

A walker's track labelled moving coasts as well, for ``Coasting.moving_frames``, whether or not a
neighbour's box holds it: the segmentation loses a far walker for a frame or two (his voxels fall
under the noise limit, or into a cluster centred elsewhere), and his filter, sure of his pace,
knows where he walks better than a ghost is credited for. Found again far from its prediction, a
coasting track restarts its speed window as a revived ghost does (core.py). Synthetic crossing
held out: 75.2 -> 77.9 % moving TP (docs/results/tracking.md, "Session 43").

A standing upright track coasts too, for ``Coasting.standing_frames``: a far pole's cluster is
missing or centred off it in a frame now and then, and its track knows where it stands. Session
43 had left it a ghost at once (unseen, it may have gone: a phantom, a pole's fragment); held one
frame, stationary recall rose on every seed set with obstacle precision within 0.001, and a
phantom is kept from coasting by ``Coasting.min_age`` (younger tracks coasting cost precision;
docs/results/tracking.md, "Session 58").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from services.tracker.fragments import claims
from services.tracker.track import ACCEPTANCE, GHOST, TRACKED, TrackTable

NDArray = npt.NDArray[Any]


@dataclass(frozen=True)
class Coasting:
    """How long an upright track may stay tracked while merged into a neighbour's cluster, or unseen while
    labelled moving or standing, and from what age (the module's docstring says why each)."""

    frames: int = 0  # 0: never
    min_age: int = 0  # frames of track
    max_speed: float = float("inf")  # m/s, horizontal
    moving_frames: int = 0  # an upright track labelled moving coasts this long, merged or not; 0: never
    standing_frames: int = 0  # ... and one labelled standing, merged or not; 0: never


#: tracks never coast: unseen is a ghost.
NO_COASTING = Coasting()


def coasts(tracks: TrackTable, seen: NDArray, elapsed: int, coasting: Coasting, upright: NDArray) -> NDArray:
    """Which tracks unseen this frame coast: upright, old enough, slow enough, and inside a seen tracked
    object's box, or tracked and labelled moving or standing (each for its own number of frames).

    Called before ``advance`` moves the counts on, so a track's misses include this frame's ``elapsed``.
    """
    t = tracks
    out = np.zeros(len(t), dtype=bool)
    if coasting.frames <= 0 and coasting.moving_frames <= 0 and coasting.standing_frames <= 0:
        return out
    candidate = ~seen & (t.queue != ACCEPTANCE) & upright
    candidate &= (t.age >= coasting.min_age) & (np.hypot(t.x[:, 3], t.x[:, 4]) <= coasting.max_speed)
    out = candidate & t.moving & (t.misses + elapsed <= coasting.moving_frames) & (t.queue == TRACKED)
    out |= candidate & ~t.moving & (t.misses + elapsed <= coasting.standing_frames) & (t.queue == TRACKED)
    candidate &= t.misses + elapsed <= coasting.frames
    known = seen & (t.queue == TRACKED)
    if candidate.any() and known.any():
        where = t.x[candidate, 0:3] + t.offset[candidate]  # where the track reports itself
        out[candidate] |= claims(where, t.bbox_min[known], t.bbox_max[known], 0.0).any(axis=0)
    return out


def advance(
    tracks: TrackTable,
    seen: NDArray,
    elapsed: int,
    accept_frames: int,
    ghost_frames: int,
    held: NDArray | None = None,
    accept_misses: int = 0,
    coast: NDArray | None = None,
) -> NDArray:
    """Move every track to its queue for this frame; return the mask of tracks to keep.

    ``seen`` marks the tracks associated with a cluster this frame; ``elapsed`` is the number of
    frames since the previous processed one (1 without a gap); ``held`` marks acceptance tracks
    not to promote yet (a piece inside a known object, see fragments.py); ``coast`` marks unseen
    tracks that stay or turn tracked (``coasts``).
    """
    tracks.age += elapsed
    tracks.misses = np.where(seen, 0, tracks.misses + elapsed)
    was = tracks.queue
    # an acceptance track within its allowance of misses keeps its count of frames seen
    keeps_count = (was == ACCEPTANCE) & (tracks.misses <= accept_misses)
    tracks.hits = np.where(seen, tracks.hits + 1, np.where(keeps_count, tracks.hits, 0))
    queue = was.copy()
    ready = seen & (was == ACCEPTANCE) & (tracks.hits >= accept_frames)
    if held is not None:
        ready &= ~held
    queue[ready] = TRACKED
    queue[seen & (was == GHOST)] = TRACKED
    queue[~seen & (was == TRACKED)] = GHOST
    if coast is not None:
        queue[coast] = TRACKED
    tracks.queue = queue
    # a ghost, or a track coasting, is retired after ``ghost_frames`` unseen
    lost = (was == ACCEPTANCE) & (tracks.misses > accept_misses)
    lost |= (queue != ACCEPTANCE) & (tracks.misses > ghost_frames)
    dropped = ~seen & lost
    return ~dropped
