"""Parts whose corners move apart across the line of sight are not joined (services/voxel_mapper/apart.py)."""

from __future__ import annotations

import numpy as np
import pytest
from test_voxel_mapper import BLUE, GREY, RED, box, ego, mapper, road

from common.errors import ConfigError
from common.messages import PointCloud
from services.voxel_mapper.apart import Apart, ApartRule, PartMotion
from services.voxel_mapper.linkage import _join_unless_apart

RULE = ApartRule(min_corners=3)
PERIOD_NS = 100_000_000


def test_parts_are_apart_only_when_their_corners_are_sure_they_move_apart_and_one_stands() -> None:
    # parts: a walker crossing, a wall, a doubtful walker, two parts moving alike, too few corners
    apart = Apart(RULE, known=np.array([True, True, True, True, False]),
                  across=np.array([0.6, 0.0, 0.6, 0.5, 1.5]), sigma=np.array([0.06, 0.08, 0.3, 0.05, 0.05]))
    pairs = [(0, 1), (1, 0), (2, 1), (0, 3), (4, 1)]
    a, b = np.array(pairs).T
    assert apart(a, b).tolist() == [True, True, False, False, False]
    # two parts that both move, 0.6 m/s apart: kept apart only when no part need stand
    moving = Apart(RULE, known=np.array([True, True]), across=np.array([0.9, 0.3]), sigma=np.array([0.05, 0.05]))
    assert not moving(np.array([0]), np.array([1]))[0]
    either = Apart(ApartRule(min_corners=3, still_mps=0.0), moving.known, moving.across, moving.sigma)
    assert either(np.array([0]), np.array([1]))[0]


def test_a_part_linked_to_a_wall_through_one_without_corners_stays_off_the_wall() -> None:
    # 0: a walker's coat (moving corners), 1: his trousers (none), 2: the wall (standing corners)
    apart = Apart(RULE, known=np.array([True, False, True]), across=np.array([0.7, 0.0, 0.0]),
                  sigma=np.array([0.05, np.inf, 0.05]))
    xs, ys = np.array([0, 1]), np.array([1, 2])
    coat_first = np.arange(3)
    _join_unless_apart(coat_first, xs, ys, np.array([0.9, 0.4]), apart)
    assert coat_first.tolist() == [0, 0, 2]  # coat and trousers joined; the wall alone
    wall_first = np.arange(3)
    _join_unless_apart(wall_first, xs, ys, np.array([0.4, 0.9]), apart)
    assert wall_first.tolist() == [0, 1, 1]  # the trousers went to the wall first: the coat stays alone
    none = Apart(RULE, known=np.zeros(3, dtype=bool), across=np.zeros(3), sigma=np.full(3, np.inf))
    everything = np.arange(3)
    _join_unless_apart(everything, xs, ys, np.array([0.9, 0.4]), none)
    assert everything.tolist() == [0, 0, 0]


def _walker_by_a_wall(frame: int, speed: float) -> PointCloud:
    """A wall across the view 12 m ahead, and before it, touching it, a runner of a red coat and blue
    trousers crossing at ``speed``; six corners on each of his parts and ten on the wall. His parts
    fill whole voxels (coat and trousers 12 each) wherever he is at 0 or 2.5 m/s."""
    y = -1.0 + speed * 0.1 * frame
    coat = box((11.52, y + 0.02, 1.02), (11.98, y + 0.48, 1.73), RED)
    legs = box((11.52, y + 0.02, 0.27), (11.98, y + 0.48, 0.98), BLUE, seed=3)
    wall = box((12.0, -4.0, 0.0), (12.3, 4.0, 2.4), GREY, seed=5)
    parts = (road(), coat, legs, wall)
    corners = np.array(
        [[11.52, y + dy, z] for z in (1.1, 1.4, 1.6) for dy in (0.1, 0.4)]  # on the coat
        + [[11.52, y + dy, z] for z in (0.35, 0.6, 0.85) for dy in (0.1, 0.4)]  # on the trousers
        + [[12.0, wy, wz] for wy in (-3.0, -2.0, 2.0, 3.0, 3.5) for wz in (0.8, 1.8)]  # on the wall
    )
    return PointCloud(frame_id=frame, stamp_ns=frame * PERIOD_NS, points=np.concatenate([p for p, _ in parts]),
                      colors=np.concatenate([c for _, c in parts]), keypoint_ids=np.arange(len(corners)),
                      keypoints=corners.astype(np.float32), keypoint_std=np.full(len(corners), 0.05, np.float32))


def _clusters_at_the_end(speed: float, **voxel: object) -> list[tuple[float, float]]:
    m = mapper(**voxel)
    for frame in range(6):
        out = m.process(_walker_by_a_wall(frame, speed), ego(frame_id=frame))
    return sorted((round(float(c.centroid[1]), 1), c.bbox_max[1] - c.bbox_min[1]) for c in out.clusters)


def test_a_runner_crossing_before_a_wall_is_kept_off_it_by_his_corners() -> None:
    rule = {"join_model": ""}  # the share rule, which the corners guard
    # linked along his whole back, the fill's parts are joined into one object by the share rule
    assert len(_clusters_at_the_end(2.5, apart_min_corners=0, **rule)) == 1
    walker, wall = sorted(_clusters_at_the_end(2.5, **rule), key=lambda c: c[1])
    assert walker[0] == pytest.approx(-1.0 + 2.5 * 0.5 + 0.25, abs=0.1)  # coat and trousers, one cluster
    assert walker[1] < 0.6 and wall[1] > 7.5
    # standing by the wall, the rule joins him to it again
    assert len(_clusters_at_the_end(0.0, **rule)) == 1
    # the learned linkage (session 53) doubts both joins: he stays off the wall, running or standing
    assert len(_clusters_at_the_end(2.5, apart_min_corners=0)) == 2
    assert len(_clusters_at_the_end(0.0)) == 2


def test_a_replayed_recording_starts_every_corners_history_afresh() -> None:
    motion = PartMotion(RULE)
    ids, corners, std = np.arange(3), np.zeros((3, 3)), np.full(3, 0.05)
    for frame in range(4):
        motion.follow(ids, corners, std, np.ones(3, dtype=bool), frame * PERIOD_NS, world_epoch=0)
    assert motion.history.n.tolist() == [4, 4, 4]
    motion.follow(ids, corners, std, np.zeros(3, dtype=bool), 4 * PERIOD_NS, world_epoch=0)
    assert motion.history.n.tolist() == [5, 5, 5]  # followed last frame, followed still
    motion.follow(ids, corners, std, np.ones(3, dtype=bool), 0, world_epoch=0)
    assert motion.history.n.tolist() == [1, 1, 1]
    motion.follow(ids[:1], corners[:1], std[:1], np.ones(1, dtype=bool), PERIOD_NS, world_epoch=1)
    assert motion.history.ids.tolist() == [0] and motion.history.n.tolist() == [1]


@pytest.mark.parametrize(
    "fields",
    [dict(min_corners=-1), dict(across_mps=-0.1), dict(sigma_k=-1.0), dict(still_mps=-0.2),
     dict(min_corners=3, samples=1)],
)
def test_bad_apart_settings_are_refused(fields: dict[str, float]) -> None:
    with pytest.raises(ConfigError, match=r"voxel\.apart_"):
        ApartRule(**fields)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"voxel\.apart_"):
        mapper(**{f"apart_{name}": value for name, value in fields.items()})
