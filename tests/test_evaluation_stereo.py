"""D1 on hand-made disparity pairs, including KITTI's background interpolation, and the SGBM anchor reproduced."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import shared_path

from common.datasets import kitti_raw, middlebury
from common.evaluation.stereo import d1_frame, interpolate_background
from common.recording import open_recording

N = np.nan


def test_interpolation_takes_the_farther_neighbour_and_extends_row_ends() -> None:
    disp = np.array([[N, 10, N, N, 20, 0, 30, N]], dtype=np.float32)
    filled = interpolate_background(disp)
    np.testing.assert_array_equal(filled, [[10, 10, 10, 10, 20, 20, 30, 30]])


def test_interpolation_fills_top_and_bottom_rows_but_not_a_gap_between_rows() -> None:
    disp = np.array([[N, N, N], [4, N, 8], [N, N, N], [N, 6, N], [N, N, N]], dtype=np.float32)
    filled = interpolate_background(disp)
    np.testing.assert_array_equal(filled[0], [4, 4, 8])
    np.testing.assert_array_equal(filled[1], [4, 4, 8])
    assert np.isnan(filled[2]).all()
    np.testing.assert_array_equal(filled[3], [6, 6, 6])
    np.testing.assert_array_equal(filled[4], [6, 6, 6])
    assert np.isnan(disp[0]).all(), "the input must not be modified"


def test_d1_on_a_hand_made_pair() -> None:
    truth = np.full((2, 8), 10.0, dtype=np.float32)
    truth[1, 7] = N  # no truth here: counts nowhere
    est = np.array([[10, N, N, 20, 20, N, 10, N], [N, N, N, N, N, N, N, 50]], dtype=np.float32)
    # row 0 filled: [10, 10, 10, 20, 20, 10, 10, 10] -> 2 bad; row 1 filled: all 50 -> 7 bad
    result = d1_frame(est, truth)
    assert result["d1_all_pct"] == pytest.approx(100 * 9 / 15)
    assert result["d1_est_pct"] == pytest.approx(100 * 2 / 4)  # pixel (1, 7) has no truth
    assert result["density_pct"] == pytest.approx(100 * 4 / 15)


def test_small_errors_are_not_bad_and_large_disparities_need_five_percent() -> None:
    truth = np.array([[10.0, 100.0, 100.0]], dtype=np.float32)
    est = np.array([[12.9, 104.0, 106.0]], dtype=np.float32)  # 2.9 px; 4 px = 4 %; 6 px = 6 %
    result = d1_frame(est, truth)
    assert result["d1_est_pct"] == pytest.approx(100 / 3)
    assert result["d1_all_pct"] == pytest.approx(100 / 3)
    assert result["density_pct"] == pytest.approx(100.0)


def test_empty_estimate_and_empty_truth() -> None:
    truth = np.full((2, 3), 5.0, dtype=np.float32)
    empty = np.full((2, 3), N, dtype=np.float32)
    result = d1_frame(empty, truth)
    assert result == {"d1_all_pct": 100.0, "d1_est_pct": None, "density_pct": 0.0}
    assert d1_frame(truth, empty) == {"d1_all_pct": None, "d1_est_pct": None, "density_pct": None}


# ----------------------------------------------------------------------------- the anchor, reproduced

ANCHOR_SGBM = {"blockSize": 3, "P1": 216, "P2": 864, "uniquenessRatio": 10, "speckleWindowSize": 100,
               "speckleRange": 2, "disp12MaxDiff": 1, "preFilterCap": 63}


def _sgbm_scores(recording: Path, disparities: int) -> dict[str, float]:
    """../shared/anchors' OpenCV SGBM (3-way, common settings) scored by this metric, mean over truth frames."""
    reader = open_recording(recording)
    frames, truths = reader.by_topic("camera/stereo"), reader.by_topic("groundtruth/disparity")
    scores = []
    for frame_id, truth in sorted(truths.items()):
        sgbm = cv2.StereoSGBM.create(minDisparity=0, numDisparities=disparities, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
                                     **ANCHOR_SGBM)
        frame = frames[frame_id]
        est = sgbm.compute(frame.left, frame.right).astype(np.float32) / 16.0
        est[est < 0] = np.nan  # SGBM's invalid is -1
        scores.append(d1_frame(est, truth.disparity))
    return {k: float(np.mean([s[k] for s in scores])) for k in scores[0]}


@pytest.mark.timeout(240)
def test_metric_reproduces_the_sgbm_anchor_on_middlebury_and_kitti(tmp_path: Path) -> None:
    """EVALUATION.md's calibration check: the same SGBM on the same frames gives the anchors' figures."""
    mb = tmp_path / "mb.mcap"
    middlebury.import_scenes(shared_path("data", "middlebury"), mb)
    got = _sgbm_scores(mb, 64)
    assert got == pytest.approx({"d1_all_pct": 10.3, "d1_est_pct": 3.8, "density_pct": 81.0}, abs=0.6), got
    raw = tmp_path / "raw.mcap"
    kitti_raw.import_drive(shared_path("data", "kitti_raw", "2011_09_26", "2011_09_26_drive_0009_sync"), raw,
                           max_frames=51)
    got = _sgbm_scores(raw, 128)
    assert got == pytest.approx({"d1_all_pct": 16.9, "d1_est_pct": 8.9, "density_pct": 78.0}, abs=0.6), got


def test_edge_counts_find_points_between_two_surfaces_on_both_sides_of_a_step() -> None:
    from common.evaluation.edges import dense, edge_counts, format_edges

    # a row of background at 10 px with an object at 14 px on columns 20-29; the right camera
    # cannot see columns 16-19 (the hidden band, empty in the truth)
    truth = np.full((3, 40), 10.0, dtype=np.float32)
    truth[:, 20:30] = 14.0
    truth[:, 16:20] = N
    est = truth.copy()
    est[:, 14:20] = 12.0  # a ramp through the band and two background columns beyond it
    est[:, 30] = 14.0  # fattened: on the object's disparity, not between the surfaces
    est[:, 31] = 12.0  # between
    counts = edge_counts(est, truth)
    shares = counts.shares()
    assert counts.hidden.tolist() == [3] * 8 and counts.seen.tolist() == [3] * 8
    assert shares["hidden_side"] == [100.0] * 6 + [0.0, 0.0]
    assert shares["seen_side"] == [0.0, 100.0] + [0.0] * 6
    # the matcher's own truth has nothing between; a sparse (lidar) truth is not read
    clean = edge_counts(np.where(np.isnan(truth), 10.0, truth), truth)
    assert clean.hidden_between.sum() == 0 and clean.seen_between.sum() == 0
    assert dense(truth) and not dense(np.where(np.arange(40) % 4 == 0, truth, N))
    table = format_edges(counts)
    assert "beside the hidden band" in table and "100.0" in table
