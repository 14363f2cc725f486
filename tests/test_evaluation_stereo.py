"""D1 on hand-made disparity pairs, including KITTI's background interpolation."""

from __future__ import annotations

import numpy as np
import pytest

from common.evaluation.stereo import d1_frame, interpolate_background

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
