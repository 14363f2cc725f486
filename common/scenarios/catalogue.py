"""The named scenarios: each a road, a furnished street, traffic on known paths and an ego profile.

Seeds vary placements, colours and traffic; the structure that makes a scenario what it is (the
crossing, the overhanging sign, the crest) stays. Every scenario keeps moving objects in the
volume of interest for many frames: lead cars near the ego's speed, walkers on the near
sidewalk, crossings timed to happen in front of a stopped ego.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

from common.errors import ConfigError
from common.scenarios import props
from common.scenarios.road import Marking, Road, Zebra
from common.scenarios.street import WAIT_U, Street, keep_pace
from common.scenarios.world import EgoProfile, Look, Path, World

#: the stretch of road furnished, whatever the number of frames (m along the road).
S_FROM, S_TO = -15.0, 230.0
DUSK = Look(noise_sigma=3.0, exposure_ratio=1.04, blur_sigma=0.8, brightness=0.35, contrast=0.3)
CITY_MARKINGS = (Marking(0.0, period=9.0, on=3.0), Marking(-3.4), Marking(3.4))
#: m/s^2 a walker sets off and stops at: 1.4-1.8 m/s within about a second, two steps of gait
#: initiation, not in one 0.1 s frame (which no filter can follow and no walker does)
WALKER_ACCEL = 1.5
#: a car's length and the distance it keeps to the one ahead in its lane (m)
CAR_GAP_M = 6.0


@dataclass(frozen=True)
class Scenario:
    name: str
    summary: str
    build: Callable[[int], World]


def _oncoming(street: Street, d: float, seed_stream: int, speed: tuple[float, float], spacing: float) -> None:
    """A stream of oncoming cars in one lane, spaced so one is always approaching; none catches up."""
    rng = street.rng(seed_stream)
    s = 35.0 + rng.uniform(0, 10)
    drawn = []
    while s < S_TO + 150:
        drawn.append((s, -rng.uniform(*speed), props.pick(rng, props.CAR_COLOURS)))
        s += spacing + rng.uniform(-5, 10)
    paced = keep_pace([(s, v) for s, v, _ in drawn], gap=CAR_GAP_M)
    for (s, _, colour), v in zip(drawn, paced, strict=True):
        street.add(props.car, Path(s, d, vs=v, yaw=math.pi), colour)


def urban(seed: int) -> World:
    road = Road(y0=1.6, curve_start=40.0, radius=120.0, markings=CITY_MARKINGS)
    street = Street(seed, road)
    rng = street.rng(1)
    for side in (-1, 1):  # on the near side a bike lane along the kerb instead of parked cars
        street.frontage(side, S_FROM, S_TO)
        street.furniture(side, S_FROM, S_TO)
        if side > 0:
            street.parked(side, S_FROM, S_TO, share=0.65)
        street.walkers(side, S_FROM, S_TO, spacing=(4.0, 10.0))
    lead = Path(rng.uniform(13, 18), -1.6, vs=rng.uniform(10.8, 11.2))
    street.add(props.car, lead, props.pick(rng, props.CAR_COLOURS))
    # cyclists in the bike lane, 0.8 m from the kerb and 3.6 m right of the ego, passed one after another
    riders = [(start + rng.uniform(-2, 4), rng.uniform(5.0, 6.5), props.pick(rng, props.CLOTHES))
              for start in (10.0, 35.0, 60.0)]
    paced = keep_pace([(s, v) for s, v, _ in riders], gap=3.0)
    for (s, _, colour), v in zip(riders, paced, strict=True):
        street.add(props.cyclist, Path(s, -(road.half_width - 0.8), vs=v), colour)
    _oncoming(street, 1.6, 2, (8.0, 10.0), 35.0)
    ego = EgoProfile((0.0, 3.0, 6.0, 9.0, 30.0), (10.0, 11.5, 9.0, 10.0, 10.0), d=-1.6)
    return World("urban", road, tuple(street.things), ego)


def crossing(seed: int) -> World:
    zebra = (32.0, 38.0)
    road = Road(y0=1.6, markings=CITY_MARKINGS, zebras=(Zebra(*zebra),))
    street = Street(seed, road)
    rng = street.rng(1)
    junction = (40.0, 52.0)
    # walkers cross from both kerbs while the ego waits; they clear its lane before it moves off.
    # Each sets off and stops at WALKER_ACCEL, so the crossing takes speed / WALKER_ACCEL longer.
    # Each has its own place across the zebra's width, where it waits at the kerb, walks and ends
    # up at the far kerb, so walkers from the two kerbs pass each other and nobody walks into anybody
    kerb = road.half_width + WAIT_U
    slot = (zebra[1] - zebra[0]) / 8
    places = rng.permutation(8)
    for k in range(8):
        side = -1 if k % 2 == 0 else 1
        speed = rng.uniform(1.4, 1.8)
        start = 0.05 + 0.35 * k + rng.uniform(0, 0.3)
        s = zebra[0] + (places[k] + 0.5) * slot + rng.uniform(-0.08, 0.08)
        end = start + 2 * kerb / speed + speed / WALKER_ACCEL
        path = Path(s, side * kerb, vd=-side * speed, t_start=start, t_end=end, yaw=-side * math.pi / 2,
                    accel=WALKER_ACCEL)
        street.place(props.pedestrian, path, props.pick(rng, props.CLOTHES), props.pick(rng, props.CLOTHES[:3]))
    # cars crossing on the side road, one each way, while the ego stands
    for side, start, lane in ((-1, 1.05, 47.6), (1, 4.05, 44.4)):
        v = rng.uniform(6.0, 8.0)
        path = Path(lane, side * 35.0, vd=-side * v, t_start=start, t_end=start + 70.0 / v, yaw=-side * math.pi / 2)
        street.add(props.car, path, props.pick(rng, props.CAR_COLOURS))
    # the sidewalks last: their walkers keep clear of the crossing walkers and cars
    street.street(S_FROM, S_TO, gaps=((zebra[0] - 4, junction[1]),))
    # a lorry queueing in the oncoming lane, beside the stopped ego: a third of the view
    street.add(props.truck, Path(rng.uniform(24.0, 26.0), 1.7, yaw=math.pi), props.pick(rng, props.FACADES))
    ego = EgoProfile((0.0, 1.0, 4.0, 9.0, 11.0, 30.0), (8.0, 8.0, 0.0, 0.0, 6.0, 8.0), d=-1.6)
    return World("crossing", road, tuple(street.things), ego)


def overtake(seed: int) -> World:
    # three lanes one way (ego in the middle) and one lane oncoming, beyond a solid line
    markings = (Marking(-3.5, period=9.0, on=3.0), Marking(0.0, period=9.0, on=3.0), Marking(3.5))
    road = Road(y0=1.75, half_width=7.0, curve_start=90.0, radius=-300.0, markings=markings)
    street = Street(seed, road)
    rng = street.rng(1)
    for side in (-1, 1):
        street.frontage(side, S_FROM, S_TO + 150)
        street.furniture(side, S_FROM, S_TO + 150)
    street.walkers(-1, S_FROM, S_TO + 150, moving_share=0.5)
    same = (
        (props.car, rng.uniform(14, 18), -5.25, rng.uniform(7.5, 8.5)),  # overtaken: 4 m/s slower
        (props.truck, rng.uniform(34, 40), -5.25, rng.uniform(9.5, 10.5)),  # overtaken slowly
        (props.car, rng.uniform(-10, -6), 1.75, rng.uniform(15.5, 16.5)),  # overtakes the ego on the left
        (props.car, rng.uniform(17, 22), -1.75, rng.uniform(12.8, 13.2)),  # lead car, about the same speed
    )
    for make, s0, d, v in same:
        street.add(make, Path(s0, d, vs=v), props.pick(rng, props.CAR_COLOURS))
    _oncoming(street, 5.25, 2, (7.0, 8.5), 30.0)
    ego = EgoProfile((0.0, 30.0), (12.0, 12.0), d=-1.75)
    return World("overtake", road, tuple(street.things), ego)


def hanging(seed: int) -> World:
    road = Road(y0=1.6, markings=CITY_MARKINGS)
    street = Street(seed, road)
    rng = street.rng(1)
    works = ((18.0, 24.0), (33.0, 40.0), (52.0, 60.0))
    reach = 5.2
    street.add(props.cantilever_sign, Path(20.0, -(road.half_width + 0.4) + reach / 2), reach, (0.1, 0.3, 0.7))
    street.add(props.gantry, Path(37.0, 0.0), 2 * road.half_width + 1.0, 2.8, (0.85, 0.65, 0.1))
    street.add(props.u_fence, Path(rng.uniform(54, 58), -4.6), 3.0, 2.2, (0.85, 0.3, 0.15))
    street.add(props.u_fence, Path(rng.uniform(75, 85), 4.6, yaw=math.pi), 3.0, 2.2, (0.85, 0.3, 0.15))
    street.street(S_FROM, S_TO, gaps=works)  # after the works: parked cars keep clear of the fences
    lead = Path(rng.uniform(12, 16), -1.6, vs=rng.uniform(7.0, 7.3))
    street.add(props.car, lead, props.pick(rng, props.CAR_COLOURS))
    _oncoming(street, 1.6, 2, (6.0, 8.0), 40.0)
    ego = EgoProfile((0.0, 3.0, 5.0, 8.0, 30.0), (7.0, 5.0, 5.0, 7.0, 7.0), d=-1.6)
    return World("hanging", road, tuple(street.things), ego)


def slope(seed: int) -> World:
    xs = (0.0, 15.0, 25.0, 60.0, 70.0, 80.0, 260.0)
    zs = (0.0, 0.0, 0.3, 2.4, 2.7, 2.6, 2.6 - 0.04 * 180.0)
    road = Road(y0=1.6, profile_x=xs, profile_z=zs, markings=CITY_MARKINGS)
    street = Street(seed, road)
    rng = street.rng(1)
    street.street(S_FROM, S_TO)
    lead = Path(rng.uniform(14, 18), -1.6, vs=rng.uniform(10.3, 10.6))
    street.add(props.car, lead, props.pick(rng, props.CAR_COLOURS))
    _oncoming(street, 1.6, 2, (8.0, 10.0), 35.0)
    ego = EgoProfile((0.0, 30.0), (10.0, 10.0), d=-1.6)
    return World("slope", road, tuple(street.things), ego)


def lowtexture(seed: int) -> World:
    return dataclasses.replace(urban(seed), name="lowtexture", look=DUSK)


SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        Scenario("urban", "city street, ego 9-11.5 m/s into a bend; parked and moving cars, walkers, "
                 "cyclists in a bike lane", urban),
        Scenario("crossing", f"stop-and-go at a zebra: walkers (setting off and stopping at {WALKER_ACCEL} m/s^2) "
                 "and two cars cross ahead; a lorry fills a third of the view", crossing),
        Scenario("overtake", "three lanes one way at 12 m/s: overtaking, overtaken, lead and oncoming traffic "
                 "(0-20 m/s relative)", overtake),
        Scenario("hanging", "an overhanging sign, a height barrier over the road, U-shaped (concave) fences", hanging),
        Scenario("slope", "6 % climb to a crest and down again: the flat-road assumption fails", slope),
        Scenario("lowtexture", "the urban street at dusk: dark, low contrast, noisy", lowtexture),
    )
}


def build(name: str, seed: int, dusk: bool = False) -> World:
    """The world of a named scenario; an unknown name raises ConfigError listing the valid ones."""
    scenario = SCENARIOS.get(name)
    if scenario is None:
        raise ConfigError(f"unknown scenario {name!r}; valid: {', '.join(SCENARIOS)}")
    world = scenario.build(seed)
    return dataclasses.replace(world, look=DUSK) if dusk else world
