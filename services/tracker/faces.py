"""Which face of its clusters a track follows, and the shift of its state when that changes.

The filter measures one point of each cluster (anchor.py): the side face in view, and the near
end unless the image's side edge cuts it. When the cluster turns another face to the camera, the
track moves its state by the difference of the two faces on this same cluster, so the change of
face is not taken for motion.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from services.tracker import motion_window
from services.tracker.observations import Observations
from services.tracker.track import TrackTable

NDArray = npt.NDArray[Any]


def turn_sides(t: TrackTable, rows: NDArray, obs: Observations) -> None:
    """Follow the side face now in view, shifting the state by that face's offset on this cluster."""
    turned = np.flatnonzero(t.side[rows] != obs.side)
    if len(turned) == 0:
        return
    rows_turned = rows[turned]
    now = obs.anchors[turned, obs.side[turned]]
    before = obs.anchors[turned, t.side[rows_turned]]
    t.x[rows_turned, 0:3] += now - before
    motion_window.shift(t.window, rows_turned, now - before)
    motion_window.shift(t.window_far, rows_turned, now - before)
    t.side[rows_turned] = obs.side[turned]


def turn_ends(t: TrackTable, rows: NDArray, obs: Observations) -> None:
    """Follow the far end of a cluster the image's side edge cuts, and the near end again once it does not.

    The state shifts by the cluster's length, as for a side face (``turn_sides``); the speed
    windows keep both ends apart and need no shift.
    """
    turned = np.flatnonzero(t.end[rows] != obs.cut)
    if len(turned) == 0:
        return
    rows_turned = rows[turned]
    sign = np.where(obs.cut[turned], 1.0, -1.0)
    t.x[rows_turned, 0:3] += sign[:, None] * obs.far[turned]
    t.end[rows_turned] = obs.cut[turned]
