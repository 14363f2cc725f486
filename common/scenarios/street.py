"""Furnishing a road: frontage (buildings, walls, kiosks), poles and bins, parked cars, walkers.

Each kind of object draws from its own random stream (seeded by the scenario seed and the kind),
so a seed fixes the whole street and adding one kind of object does not reshuffle the others.
Objects are laid out along the whole stretch the ego can reach, independent of how many frames
are rendered, so a short run is the beginning of a long one.

A sidewalk is laid out as a real one is, measured from the kerb: a furniture strip (poles, bins,
people waiting at the kerb), then two walking lanes, one for each direction, then the frontage.
Walkers in a lane never catch up with the one ahead, and nothing is placed where it would meet
something already there (``clearance``), so no two bodies ever share volume.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable

import numpy as np

from common.scenarios import props
from common.scenarios.clearance import HORIZON_S, Register
from common.scenarios.road import Road
from common.scenarios.world import Path, Thing

Gap = tuple[float, float]

#: distances from the kerb (m) on a 2.5 m sidewalk: poles and bins stand in the furniture strip,
#: people wait at the kerb between them, walkers keep to one lane for each direction (their
#: bodies are 0.52 m wide), and the frontage begins at the back of the sidewalk
POLE_U, BIN_U, WAIT_U = 0.4, 0.5, 0.5
LANE_U = {1: 1.2, -1: 1.95}
#: how close (m) the generator lets two bodies come, and how many places a standing walker tries
CLEARANCE_M = 0.05
TRIES = 4


class Street:
    """Collects the objects of one scenario and hands out ids in order."""

    def __init__(self, seed: int, road: Road) -> None:
        self.seed = seed
        self.road = road
        self.things: list[Thing] = []
        self.register = Register(road, CLEARANCE_M)

    def rng(self, stream: int) -> np.random.Generator:
        return np.random.default_rng([self.seed, stream])

    def add(self, make: Callable[..., Thing], *args: object) -> Thing:
        thing = make(len(self.things) + 1, *args)
        self.things.append(thing)
        self.register.add(thing)
        return thing

    def place(self, make: Callable[..., Thing], *args: object) -> Thing | None:
        """Add the object unless it would meet something already placed, at any time."""
        thing = make(len(self.things) + 1, *args)
        prints = self.register.footprints(thing)
        if self.register.meetings(prints):
            return None
        self.things.append(thing)
        self.register.add(thing, prints)
        return thing

    def frontage(self, side: int, s_from: float, s_to: float, gaps: tuple[Gap, ...] = ()) -> None:
        """Buildings, walls and kiosks along the back of one sidewalk (side +1 left, -1 right)."""
        rng = self.rng(10 + side)
        back = self.road.half_width + self.road.sidewalk
        s = s_from
        while s < s_to:
            kind = rng.choice(["building", "wall", "kiosk"], p=[0.45, 0.4, 0.15])
            if kind == "building":
                length, depth, height = rng.uniform(8, 20), rng.uniform(7, 11), rng.uniform(6, 14)
                d, size, cls = back + 0.3 + depth / 2, (length, depth, height), "building"
                rgb, amp = props.pick(rng, props.FACADES), 0.2
            elif kind == "wall":
                length, height = rng.uniform(6, 15), rng.uniform(1.6, 2.6)
                d, size, cls = back + 0.15, (length, 0.3, height), "wall"
                rgb, amp = props.pick(rng, props.WALLS), 0.35
            else:
                # in a recess of the frontage, in line with the buildings: the sidewalk stays clear
                length, depth, height = rng.uniform(2.5, 4), rng.uniform(1.5, 2.0), rng.uniform(2.4, 3.0)
                d, size, cls = back + 0.3 + depth / 2, (length, depth, height), "kiosk"
                rgb, amp = props.pick(rng, props.CAR_COLOURS + props.FACADES), 0.25
            mid = s + length / 2
            if not any(a - length / 2 < mid < b + length / 2 for a, b in gaps):
                self.place(props.box, cls, Path(mid, side * d), size, rgb, amp)  # on a bend the backs close in
            s += length + rng.uniform(1.0, 6.0)

    def furniture(self, side: int, s_from: float, s_to: float, gaps: tuple[Gap, ...] = ()) -> None:
        """Poles in the furniture strip and bins beside them."""
        rng = self.rng(20 + side)
        s = s_from + rng.uniform(0, 8)
        while s < s_to:
            if not _in_gaps(s, gaps):
                d = side * (self.road.half_width + POLE_U)
                height = rng.uniform(3.0, 5.0)
                self.place(props.box, "pole", Path(s, d), (0.16, 0.16, height), props.pick(rng, props.WALLS), 0.2, 0.01)
                if rng.random() < 0.5:
                    colour = props.pick(rng, ((0.2, 0.4, 0.25), (0.3, 0.3, 0.3), (0.6, 0.5, 0.2)))
                    bin_path = Path(s + rng.uniform(1.0, 3.0), side * (self.road.half_width + BIN_U))
                    self.place(props.box, "bin", bin_path, (0.6, 0.6, 1.0), colour, 0.25, 0.01)
            s += rng.uniform(10, 22)

    def parked(self, side: int, s_from: float, s_to: float, gaps: tuple[Gap, ...] = (), share: float = 0.65) -> None:
        """Parked cars in the parking strip; some take the colour of the walls behind them."""
        rng = self.rng(30 + side)
        d = side * (self.road.half_width - 1.1)
        s = s_from + rng.uniform(0, 5)
        while s < s_to:
            if rng.random() < share and not _in_gaps(s, gaps):
                palette = props.WALLS if rng.random() < 0.2 else props.CAR_COLOURS
                yaw = 0.0 if side < 0 else math.pi
                self.place(props.car, Path(s, d, yaw=yaw), props.pick(rng, palette))
            s += rng.uniform(5.5, 9.0)

    def walkers(self, side: int, s_from: float, s_to: float, moving_share: float = 0.7,
                spacing: tuple[float, float] = (7.0, 15.0)) -> None:
        """Pedestrians on a sidewalk, walking either way at 1.4-1.9 m/s or waiting at the kerb.

        A walker faster than the one ahead in its lane is slowed so that he never reaches him, as
        nobody walks through anybody; one whose lane is crossed by traffic while he passes is left out,
        and one waiting at the kerb takes the first place clear of the poles and bins.
        """
        rng = self.rng(40 + side)
        s = s_from + rng.uniform(0, 6)
        drawn: list[tuple[float, float, float, tuple[float, float, float], tuple[float, float, float]]] = []
        while s < s_to:
            lateral = rng.uniform(-0.05, 0.05)
            clothes = props.pick(rng, props.CLOTHES)
            legs = clothes if rng.random() < 0.4 else props.pick(rng, props.CLOTHES[:3])
            if rng.random() < moving_share:
                speed = rng.uniform(1.4, 1.9) * (1 if rng.random() < 0.6 else -1)
                drawn.append((s, speed, lateral, clothes, legs))
            else:
                drawn.append((s, 0.0, rng.uniform(-math.pi, math.pi), clothes, legs))
            s += rng.uniform(*spacing)
        paced = keep_pace([(s, v) for s, v, *_ in drawn], gap=1.0)
        for (s, _, turn, clothes, legs), speed in zip(drawn, paced, strict=True):
            if speed == 0.0:
                d = side * (self.road.half_width + WAIT_U)
                for k in range(TRIES):
                    if self.place(props.pedestrian, Path(s + 0.7 * k, d, yaw=turn), clothes, legs):
                        break
            else:
                d = side * (self.road.half_width + LANE_U[1 if speed > 0 else -1] + turn)
                path = Path(s, d, vs=speed, yaw=0.0 if speed > 0 else math.pi)
                self.place(props.pedestrian, path, clothes, legs)

    def street(self, s_from: float, s_to: float, gaps: tuple[Gap, ...] = (), parking: bool = True,
               spacing: tuple[float, float] = (7.0, 15.0)) -> None:
        """Both sides of an ordinary city street; ``spacing`` is the gap between walkers (m)."""
        for side in (-1, 1):
            self.frontage(side, s_from, s_to, gaps)
            self.furniture(side, s_from, s_to, gaps)
            if parking:
                self.parked(side, s_from, s_to, gaps)
            self.walkers(side, s_from, s_to, spacing=spacing)


def keep_pace(movers: list[tuple[float, float]], gap: float, horizon: float = HORIZON_S) -> list[float]:
    """Speeds along s of objects in one lane, slowed so none reaches the one ahead within ``horizon``.

    ``movers`` are (s, signed speed); objects going either way share the list but only meet
    those going their own way (opposite directions keep to their own lanes). ``gap`` is the
    length of a body plus the distance kept (m). A zero speed is left as it is.
    """
    speeds = [v for _, v in movers]
    for direction in (1, -1):
        lane = sorted((i for i, (_, v) in enumerate(movers) if v * direction > 0),
                      key=lambda i: -direction * movers[i][0])  # the leader first
        for ahead, behind in itertools.pairwise(lane):
            room = abs(movers[ahead][0] - movers[behind][0]) - gap
            limit = abs(speeds[ahead]) + max(room, 0.0) / horizon
            speeds[behind] = direction * min(abs(speeds[behind]), limit)
    return speeds


def _in_gaps(s: float, gaps: tuple[Gap, ...]) -> bool:
    return any(a <= s <= b for a, b in gaps)
