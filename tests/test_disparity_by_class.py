"""scripts/disparity_by_class.py: silhouette columns found along rows, errors tallied per class and band."""

from __future__ import annotations

from collections import defaultdict

import numpy as np
from conftest import load_script


def test_row_distance_counts_columns_to_another_surface_along_the_row_only() -> None:
    tool = load_script("disparity_by_class")
    ids = np.full((3, 9), -1, np.int32)
    ids[:, 2:9] = 5  # an object from column 2 to the image's right border
    dist = tool.row_distance(ids)
    assert dist[0].tolist() == [2, 1, 1, 2, 3, 3, 3, 3, 3]  # the border at column 8 is no surface
    assert (dist == dist[0]).all()  # rows alike: nothing is measured across them


def test_one_object_offset_by_a_known_error_reports_it_in_every_band() -> None:
    tool = load_script("disparity_by_class")
    ids = np.full((30, 20), -1, np.int32)
    ids[:, 5:15] = 3  # a pole 10 px wide: columns 1 and 2 on both sides, 6 inside
    truth = np.full(ids.shape, 10.0, np.float32)  # 24 m on the synthetic rig
    depth = 240.0 / truth
    estimate = truth.copy()
    estimate[ids == 3] -= 0.5  # the whole pole half a pixel too far
    estimate[0, 5] = np.nan  # one pixel of its edge without an estimate
    tallies = defaultdict(tool.ClassTally)
    tool.tally_frame(tallies, estimate, truth, depth, ids, {3: "pole"}, (15.0, 29.0))
    pole = tallies["pole"]
    assert pole.medians == [-0.5]
    assert pole.pixels == {"column 1": 60, "column 2": 60, "inside": 180}
    assert pole.invalid["column 1"] == 1
    assert pole.off["column 1"] == pole.behind["column 1"] == 59
    assert pole.off["inside"] == pole.behind["inside"] == 180
    assert set(tallies) == {"pole"}  # the ground (-1) is no object


def test_objects_outside_the_depth_band_are_left_out() -> None:
    tool = load_script("disparity_by_class")
    ids = np.full((10, 10), 4, np.int32)
    truth = np.full(ids.shape, 40.0, np.float32)  # 6 m away
    tallies = defaultdict(tool.ClassTally)
    tool.tally_frame(tallies, truth + 1.0, truth, 240.0 / truth, ids, {4: "car"}, (15.0, 29.0))
    assert not tallies
