"""The odometry metric on hand-made trajectories with known answers, and on the VISO2-S anchor."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import shared_path

from common.evaluation.odometry import load_kitti_poses, odometry_errors
from common.geometry import make_pose, rot_y


def straight(frames: int, step: float, scale: float = 1.0) -> list[np.ndarray]:
    """Camera moving along its z axis (forward) by ``step`` metres a frame."""
    return [make_pose(np.eye(3), [0.0, 0.0, scale * step * i]) for i in range(frames)]


def test_perfect_odometry_has_zero_error() -> None:
    truth = straight(31, 1.0)
    result = odometry_errors(truth, truth)
    assert result == {"t_err_pct": 0.0, "r_err_deg_per_m": 0.0, "final_drift_pct": 0.0}


def test_constant_scale_drift_gives_known_t_err() -> None:
    # 31 frames 1 m apart: a 10 m segment ends 11 m on (the first frame *beyond* L), 20 starts
    # fit; a 20 m segment ends 21 m on, 10 starts fit; 50 and 100 m do not fit.
    truth = straight(31, 1.0)
    est = straight(31, 1.0, scale=1.02)
    result = odometry_errors(est, truth)
    assert result is not None
    expected = (20 * 0.02 * 11 / 10 + 10 * 0.02 * 21 / 20) / 30
    assert result["t_err_pct"] == pytest.approx(100 * expected)
    assert result["r_err_deg_per_m"] == pytest.approx(0.0, abs=1e-12)
    assert result["final_drift_pct"] == pytest.approx(2.0)


def test_heading_error_gives_rotation_error_per_metre() -> None:
    truth = straight(21, 1.0)
    # the estimate turns 0.01 rad a frame about the camera's vertical (y) axis
    est = [make_pose(rot_y(0.01 * i), [0.0, 0.0, float(i)]) for i in range(21)]
    result = odometry_errors(est, truth, lengths=(10.0,))
    assert result is not None
    # every 10 m segment spans 11 frames: 0.11 rad over 10 m
    assert result["r_err_deg_per_m"] == pytest.approx(np.degrees(0.11) / 10.0)


def test_too_short_a_run_gives_none() -> None:
    truth = straight(5, 1.0)
    assert odometry_errors(truth, truth) is None


def test_viso2_anchor_on_kitti_odometry_04() -> None:
    est = load_kitti_poses(str(shared_path("anchors", "viso2_odo04_poses.txt")))
    truth_cam0 = load_kitti_poses(str(shared_path("data", "kitti_odometry", "dataset", "poses", "04.txt")))[:40]
    calib = shared_path("data", "kitti_odometry", "dataset", "sequences", "04", "calib.txt")
    p2 = next(np.array(line.split()[1:], float).reshape(3, 4) for line in calib.open() if line.startswith("P2:"))
    offset = make_pose(np.eye(3), np.linalg.solve(p2[:, :3], p2[:, 3]))  # cam0 -> cam2 coordinates
    truth = [offset @ pose @ np.linalg.inv(offset) for pose in truth_cam0]
    result = odometry_errors(est, truth)
    assert result is not None
    assert result["t_err_pct"] == pytest.approx(1.68, abs=0.05)
    assert result["r_err_deg_per_m"] == pytest.approx(0.0086, abs=0.0005)
    assert result["final_drift_pct"] == pytest.approx(1.80, abs=0.05)
