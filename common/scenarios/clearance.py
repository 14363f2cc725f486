"""Whether two objects of a synthetic street ever stand in the same place.

The street is furnished kind by kind from independent random streams. Left to themselves those
streams put bins inside kiosks and let walkers pass through each other and through poles, which
no camera could see and which the evaluation then scores as misses. The generator asks this
register before it places anything that could meet something else, and the tests ask it of
every scenario, so a scene is physically possible by construction and by check.

Footprints are rectangles seen from above, in the world frame, sampled over the whole time a
street is furnished for; everything stands on the surface, so two footprints that meet are two
bodies that meet. Open structures (a gantry, a sign, a U-fence) hold free space inside their
box: for them only the parts that reach below head height count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.messages import OPEN_CLASSES
from common.scenarios.road import Road
from common.scenarios.world import Thing

F64 = npt.NDArray[np.float64]

#: seconds of motion checked: longer than any run the furnished stretch is long enough for
HORIZON_S = 30.0
#: sampling step; at the fastest closing speed between two objects that can meet (walkers head
#: on, 3.8 m/s) an object moves 0.19 m a step, less than the 0.32 m a walker is deep
STEP_S = 0.05
#: parts whose bottom is this high are overhead: walkers and cars pass beneath them
OVERHEAD_M = 2.0


@dataclass(frozen=True)
class Footprints:
    """Rectangles of one object over time: centres (t, k, 2), half sizes (k, 2), yaws (t, k)."""

    centre: F64
    half: F64
    yaw: F64


def times() -> F64:
    return np.arange(0.0, HORIZON_S + STEP_S / 2, STEP_S)


def blocks(thing: Thing) -> tuple[F64, F64]:
    """Centres in the object's frame and half sizes of the rectangles its body takes up."""
    if thing.cls not in OPEN_CLASSES:
        return np.zeros((1, 2)), np.array([thing.size[:2]]) / 2
    low = [p for p in thing.parts if p.center[2] - p.size[2] / 2 < OVERHEAD_M]
    return np.array([p.center[:2] for p in low]), np.array([p.size[:2] for p in low]) / 2


def footprints(road: Road, thing: Thing, at: F64) -> Footprints:
    """The object's rectangles at every time in ``at`` (one time only if it never moves)."""
    path = thing.path
    still = path.vs == 0.0 and path.vd == 0.0
    sample = at[:1] if still else at
    sd = np.array([path.road_at(float(t)) for t in sample])
    x, y, heading = road.to_world(sd[:, 0], sd[:, 1])
    yaw = heading + path.yaw
    local, half = blocks(thing)
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    cx = x[:, None] + c * local[None, :, 0] - s * local[None, :, 1]
    cy = y[:, None] + s * local[None, :, 0] + c * local[None, :, 1]
    return Footprints(np.stack([cx, cy], axis=-1), half, np.repeat(yaw[:, None], len(local), axis=1))


def rectangles_meet(
    ca: F64, ha: F64, ya: F64, cb: F64, hb: F64, yb: F64, clearance: float = 0.0
) -> npt.NDArray[np.bool_]:
    """Separating-axis test of rectangle arrays (broadcast): do they come closer than ``clearance``?"""
    axes_a = (np.stack([np.cos(ya), np.sin(ya)], -1), np.stack([-np.sin(ya), np.cos(ya)], -1))
    axes_b = (np.stack([np.cos(yb), np.sin(yb)], -1), np.stack([-np.sin(yb), np.cos(yb)], -1))
    gap = cb - ca
    apart = np.zeros(np.broadcast_shapes(gap.shape[:-1], ha.shape[:-1], hb.shape[:-1]), bool)
    for u in (*axes_a, *axes_b):
        reach_a = ha[..., 0] * np.abs((axes_a[0] * u).sum(-1)) + ha[..., 1] * np.abs((axes_a[1] * u).sum(-1))
        reach_b = hb[..., 0] * np.abs((axes_b[0] * u).sum(-1)) + hb[..., 1] * np.abs((axes_b[1] * u).sum(-1))
        apart |= np.abs((gap * u).sum(-1)) >= reach_a + reach_b + clearance
    return ~apart


class Register:
    """What stands where so far; ``meetings`` says what a new object would meet."""

    def __init__(self, road: Road, clearance: float = 0.0) -> None:
        self.road = road
        self.clearance = clearance
        self.at = times()
        self._parts: dict[bool, list[tuple[int, Footprints]]] = {True: [], False: []}
        self._stacked: dict[bool, tuple[Footprints, npt.NDArray[np.int64]] | None] = {True: None, False: None}

    def footprints(self, thing: Thing) -> Footprints:
        return footprints(self.road, thing, self.at)

    def add(self, thing: Thing, prints: Footprints | None = None) -> None:
        """Register ``thing``; ``prints`` are its footprints when ``meetings`` already computed them."""
        prints = self.footprints(thing) if prints is None else prints
        still = len(prints.centre) == 1
        self._parts[still].append((thing.id, prints))
        self._stacked[still] = None

    def _stack(self, still: bool) -> tuple[Footprints, npt.NDArray[np.int64]] | None:
        """All still (or all moving) objects' rectangles side by side, with their owners' ids."""
        if self._stacked[still] is None and self._parts[still]:
            parts = self._parts[still]
            prints = Footprints(
                np.concatenate([f.centre for _, f in parts], axis=1),
                np.concatenate([f.half for _, f in parts], axis=0),
                np.concatenate([f.yaw for _, f in parts], axis=1),
            )
            owners = np.concatenate([np.full(len(f.half), i) for i, f in parts])
            self._stacked[still] = (prints, owners)
        return self._stacked[still]

    def meetings(self, new: Footprints) -> list[tuple[float, int]]:
        """(first time, id) of everything an object with footprints ``new`` would meet, earliest first."""
        reach_new = np.linalg.norm(new.half, axis=-1)
        first: dict[int, float] = {}
        for still in (True, False):
            stacked = self._stack(still)
            if stacked is None:
                continue
            old, owners = stacked
            reach = reach_new[:, None] + np.linalg.norm(old.half, axis=-1)[None, :] + self.clearance
            # bounding circles first, over (time, new rectangle, old rectangle)
            near = np.linalg.norm(new.centre[:, :, None] - old.centre[:, None, :], axis=-1) < reach
            if not near.any():
                continue
            steps, rows, cols = np.nonzero(near)
            ta = steps if len(new.centre) > 1 else np.zeros_like(steps)
            tb = steps if len(old.centre) > 1 else np.zeros_like(steps)
            meet = rectangles_meet(
                new.centre[ta, rows], new.half[rows], new.yaw[ta, rows],
                old.centre[tb, cols], old.half[cols], old.yaw[tb, cols], self.clearance,
            )
            step_times = self.at[steps[meet]] if near.shape[0] > 1 else np.zeros(int(meet.sum()))
            for when, owner in zip(step_times, owners[cols[meet]], strict=True):
                first[int(owner)] = min(first.get(int(owner), np.inf), float(when))
        return sorted((t, i) for i, t in first.items())


def shared_volume(road: Road, things: tuple[Thing, ...] | list[Thing]) -> list[tuple[float, int, int]]:
    """Every pair of objects whose bodies meet at some time: (first time, earlier id, later id)."""
    register = Register(road)
    found: list[tuple[float, int, int]] = []
    for thing in things:
        prints = register.footprints(thing)
        found.extend((t, other, thing.id) for t, other in register.meetings(prints))
        register.add(thing, prints)
    return found
