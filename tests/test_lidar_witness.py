"""The floor scripts/lidar_witness.py reports: a path that only travels in another direction, scored."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from conftest import load_script

from common.evaluation.odometry import odometry_errors
from common.geometry import make_pose


def curved_path(frames: int = 1101, step_m: float = 0.05, turn_deg: float = 0.001) -> list[np.ndarray]:
    """Camera poses (x right, y down, z forward) of a car bending gently to the right over 55 m.

    Steps are short so that a segment ends within 0.5 % of its nominal length, which t_err divides by.
    """
    witness = load_script("lidar_witness")
    step = make_pose(witness.yaw_about_y(turn_deg), np.array([0.0, 0.0, step_m]))
    poses = [np.eye(4)]
    for _ in range(frames - 1):
        poses.append(poses[-1] @ step)
    return poses


def test_travel_reads_direction_length_and_turn_to_the_right_as_positive() -> None:
    witness = load_script("lidar_witness")
    motion = make_pose(witness.yaw_about_y(2.0), np.array([0.5, 0.1, 10.0]))
    direction, length, turn = witness.travel(motion)
    assert direction == pytest.approx(math.degrees(math.atan2(0.5, 10.0)))
    assert length == pytest.approx(math.sqrt(0.25 + 0.01 + 100.0))
    assert turn == pytest.approx(2.0)


def test_a_path_turned_to_travel_elsewhere_scores_the_chord_of_that_angle() -> None:
    """Every segment's end lands 2 sin(phi / 2) of its length off: the whole of t_err, no rotation error."""
    witness = load_script("lidar_witness")
    truth = curved_path()
    same = witness.turned_travel(truth, [0.0] * (len(truth) - 1))
    assert max(float(np.abs(a - b).max()) for a, b in zip(same, truth, strict=True)) < 1e-9
    turned = witness.turned_travel(truth, [1.5] * (len(truth) - 1))
    assert [witness.travel(np.linalg.inv(p) @ q)[0] for p, q in itertools.pairwise(turned[:3])] == (
        pytest.approx([1.5, 1.5])
    )
    errors = odometry_errors(turned, truth)
    assert errors is not None
    assert errors["t_err_pct"] == pytest.approx(100 * 2 * math.sin(math.radians(0.75)), rel=5e-3)
    assert errors["r_err_deg_per_m"] == pytest.approx(0.0, abs=1e-9)
