"""The paper's three queues: acceptance, tracked and ghost, and the moves between them.

- acceptance: a new cluster; promoted to tracked once seen ``accept_frames`` frames (its birth
  frame included), discarded once unseen for more than ``accept_misses`` frames in a row (the
  paper: 0, the first frame it is not seen);
- tracked: seen this frame; becomes a ghost the first frame it is not;
- ghost: not seen for ``misses`` frames; back to tracked when seen again, discarded once unseen
  for more than ``ghost_frames`` frames.
Frames lost in a gap of the input count as frames unseen, so a long gap retires ghosts.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from services.tracker.track import ACCEPTANCE, GHOST, TRACKED, TrackTable

NDArray = npt.NDArray[Any]


def advance(
    tracks: TrackTable,
    seen: NDArray,
    elapsed: int,
    accept_frames: int,
    ghost_frames: int,
    held: NDArray | None = None,
    accept_misses: int = 0,
) -> NDArray:
    """Move every track to its queue for this frame; return the mask of tracks to keep.

    ``seen`` marks the tracks associated with a cluster this frame; ``elapsed`` is the number of
    frames since the previous processed one (1 without a gap); ``held`` marks acceptance tracks
    not to promote yet (a piece inside a known object, see fragments.py).
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
    tracks.queue = queue
    lost = ((was == ACCEPTANCE) & (tracks.misses > accept_misses)) | ((queue == GHOST) & (tracks.misses > ghost_frames))
    dropped = ~seen & lost
    return ~dropped
