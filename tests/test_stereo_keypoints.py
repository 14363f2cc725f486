"""Corners followed from frame to frame with their own disparity (services/stereo_depth/keypoints.py)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from test_stereo_depth import BASELINE, FX, WIDTH, _calib, _core
from textures import blob_texture

from services.stereo_depth.keypoints import KeypointParams, Keypoints, KeypointTracker
from services.stereo_depth.reproject import Reprojector, VolumeCrop

HEIGHT = 240
DISPARITY = 20.4  # px: the wall's, off the pixel grid
PAN_PX = 3.0  # the image moves this far left each frame


def _pair(texture: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Grey left and right views of a textured wall at ``DISPARITY``, panned ``k`` frames."""
    grey = cv2.cvtColor(texture, cv2.COLOR_RGB2GRAY)
    cols = np.arange(WIDTH, dtype=np.float32)[None, :] + np.float32(PAN_PX * k)
    rows = np.broadcast_to(np.arange(HEIGHT, dtype=np.float32)[:, None], (HEIGHT, WIDTH))

    def view(shift: float) -> np.ndarray:
        map_x = np.ascontiguousarray(np.broadcast_to(cols + np.float32(shift), (HEIGHT, WIDTH)))
        return cv2.remap(grey, map_x, np.ascontiguousarray(rows), cv2.INTER_LINEAR)

    return view(40.0), view(40.0 + DISPARITY)


def _run(frames: list[int], seed: int = 0, seed_error_px: float = 0.4) -> list[Keypoints]:
    """The tracker over the given frame ids (frame k panned k times); the matcher's disparity is off by
    ``seed_error_px`` everywhere, as a whole-pixel matcher's can be."""
    texture = blob_texture(np.random.default_rng(seed), HEIGHT, WIDTH + 120)
    tracker = KeypointTracker(KeypointParams(max_count=400))
    matched = np.full((HEIGHT, WIDTH), DISPARITY + seed_error_px, dtype=np.float32)
    out = []
    for k in frames:
        left, right = _pair(texture, k)
        out.append(tracker.update(left, right, matched, k))
    return out


@pytest.mark.parametrize("seed", [0, 1])
def test_corners_keep_their_ids_move_with_the_image_and_match_their_own_disparity(seed: int) -> None:
    first, *_, last = _run([0, 1, 2, 3, 4], seed)
    assert len(first.ids) > 100
    kept, at_first, at_last = np.intersect1d(first.ids, last.ids, return_indices=True)
    assert len(kept) > 0.5 * len(first.ids)  # most are followed through four frames
    shift = last.uv[at_last] - first.uv[at_first]
    np.testing.assert_allclose(np.median(shift, axis=0), [-4 * PAN_PX, 0.0], atol=0.05)
    assert np.mean(np.abs(shift[:, 0] + 4 * PAN_PX) < 0.2) > 0.9
    # the matcher said DISPARITY + 0.4 everywhere: each corner's own match finds the wall's
    assert np.median(np.abs(last.disparity - DISPARITY)) < 0.05


def test_a_frame_older_than_the_last_starts_afresh() -> None:
    first, _, older = _run([0, 1, 0])
    assert len(np.intersect1d(first.ids, older.ids)) == 0
    assert len(older.ids) > 100


def test_new_corners_go_where_there_are_none_not_to_the_strongest() -> None:
    (first,) = _run([0])
    cell = KeypointParams().cell_px
    cells = {(int(u) // cell, int(v) // cell) for u, v in first.uv}
    assert len(cells) == len(first.uv)  # one corner per cell
    # and they spread over the whole wall: every quarter of the image holds a quarter or so
    quarters = np.histogram(first.uv[:, 0], bins=4, range=(0, WIDTH))[0]
    assert quarters.min() > 0.15 * len(first.uv)


def test_smaller_cells_take_more_corners_and_the_stage_passes_its_setting_on() -> None:
    texture = blob_texture(np.random.default_rng(2), HEIGHT, WIDTH + 120)
    left, right = _pair(texture, 0)
    matched = np.full((HEIGHT, WIDTH), DISPARITY, dtype=np.float32)
    found = {
        cell: len(KeypointTracker(KeypointParams(max_count=100_000, cell_px=cell)).update(left, right, matched, 0).ids)
        for cell in (4, 8)
    }
    assert found[4] > 2 * found[8] > 100  # a cell a quarter the area: more corners, as far as the texture has them
    core = _core(keypoint_cell_px=6)
    assert core.keypoint_tracker is not None and core.keypoint_tracker.params.cell_px == 6


def test_a_corner_without_a_disparity_from_the_matcher_is_not_placed() -> None:
    texture = blob_texture(np.random.default_rng(3), HEIGHT, WIDTH + 120)
    left, right = _pair(texture, 0)
    matched = np.full((HEIGHT, WIDTH), DISPARITY, dtype=np.float32)
    matched[:, : WIDTH // 2] = np.nan  # the left half: no match
    found = KeypointTracker(KeypointParams()).update(left, right, matched, 0)
    assert len(found.ids) > 50 and found.uv[:, 0].min() >= WIDTH // 2 - 1


def test_keypoints_are_placed_in_the_vehicle_frame_with_the_doubt_of_their_range() -> None:
    calib = _calib()
    reprojector = Reprojector(VolumeCrop(0.0, 50.0, 10.0, -1.0, 3.0), min_depth_m=1.0)
    found = Keypoints(
        ids=np.array([7, 9]), uv=np.array([[calib.cx, calib.cy], [10.0, 20.0]], dtype=np.float32),
        disparity=np.array([12.0, 400.0], dtype=np.float32),
    )  # fmt: skip
    ids, points, std = reprojector.keypoints(found, calib, disparity_std_px=0.15)
    depth = FX * BASELINE / 12.0  # 10 m; the second, 0.3 m away, is nearer than min_depth_m
    assert ids.tolist() == [7]
    np.testing.assert_allclose(points[0], [depth, 0.0, calib.cam_to_vehicle[2, 3]], atol=1e-4)
    assert std[0] == pytest.approx(0.15 * depth / 12.0)
