"""Sub-pixel refinement of SGM's disparity (services/stereo_depth/subpixel.py) on pairs the test builds."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from textures import blob_texture

from common.config_loading import load_config
from common.geometry import camera_to_vehicle
from common.messages import Calibration, StereoFrame
from services.stereo_depth import StereoDepth
from services.stereo_depth.subpixel import SubpixelParams, refine_disparity

WIDTH, HEIGHT = 320, 240
FX, BASELINE = 300.0, 0.4
NEAR = (slice(90, 150), slice(150, 210))  # rows, left-image columns of a nearer square


def _pair(d_wall: float, d_near: float | None = None, gain: float = 1.0, seed: int = 0) -> StereoFrame:
    """A textured wall at disparity ``d_wall`` (fractional), optionally a square at ``d_near`` before it.

    The right image is resampled from the left one's texture, so the shift is exact; ``gain``
    brightens the right camera, as an exposure difference would.
    """
    rng = np.random.default_rng(seed)
    wall = blob_texture(rng, HEIGHT, WIDTH + 64)
    rows = np.arange(HEIGHT, dtype=np.float32)[:, None].repeat(WIDTH, 1)
    cols = np.arange(WIDTH, dtype=np.float32)[None, :].repeat(HEIGHT, 0)
    right = cv2.remap(wall, cols + np.float32(d_wall), rows, cv2.INTER_CUBIC)
    left = wall[:, :WIDTH].copy()
    if d_near is not None:
        square = blob_texture(rng, HEIGHT, WIDTH + 64)
        r, c = NEAR
        left[r, c] = square[r, c]
        shifted = cv2.remap(square, cols + np.float32(d_near), rows, cv2.INTER_CUBIC)
        span = slice(int(np.ceil(c.start - d_near)), int(np.floor(c.stop - d_near)))
        right[r, span] = shifted[r, span]
    right = (right.astype(np.float32) * gain).clip(0, 255).astype(np.uint8)
    calib = Calibration(
        fx=FX, fy=FX, cx=WIDTH / 2, cy=HEIGHT / 2, baseline=BASELINE, width=WIDTH, height=HEIGHT,
        cam_to_vehicle=camera_to_vehicle(1.5),
    )  # fmt: skip
    return StereoFrame(frame_id=1, stamp_ns=1, left=left, right=right, calib=calib)


def _disparity(frame: StereoFrame, iterations: int) -> np.ndarray:
    # the blob texture spans a third of the grey levels, which exposure.py would treat as dusk:
    # these are tests of the daylight matcher (as test_stereo_depth.py's), on the pair as it is: the far
    # field's widened pass (far_band.py) refines in its own, half-width pixels
    sets = [f"stereo.subpixel_iterations={iterations}", "stereo.contrast_span=0", "stereo.upsample_x=1"]
    core = StereoDepth.from_config(load_config(sets=sets))
    return core.process(frame)[1].disparity


INNER = (slice(30, 210), slice(60, 300))  # away from the borders the right camera cannot see


@pytest.mark.parametrize("true_d", [12.25, 12.5, 18.3])
def test_refinement_removes_the_pull_towards_whole_pixels(true_d: float) -> None:
    """SGBM's parabola pulls a quarter- or half-pixel shift towards a whole pixel; the refinement does not."""
    frame = _pair(true_d)
    matched = _disparity(frame, 0)[INNER]
    refined = _disparity(frame, 3)[INNER]
    assert np.nanmedian(np.abs(matched - true_d)) > 0.1  # the pull is there to remove
    assert abs(np.nanmedian(refined - true_d)) < 0.02  # no bias left
    assert np.nanmedian(np.abs(refined - true_d)) < 0.07
    assert np.isfinite(refined).mean() == pytest.approx(np.isfinite(matched).mean())


def test_an_exposure_difference_is_not_read_as_a_shift() -> None:
    refined = _disparity(_pair(12.3, gain=1.15), 3)[INNER]
    assert np.nanmedian(np.abs(refined - 12.3)) < 0.05


def test_windows_across_a_depth_edge_keep_the_matchers_value() -> None:
    """The square's edge: its window holds two surfaces, so the nearer one is not dragged back."""
    frame = _pair(10.4, d_near=20.6)
    matched = _disparity(frame, 0)
    refined = _disparity(frame, 3)
    r, c = NEAR
    # its right edge: the left one borders pixels the right camera cannot see
    edge_cols = slice(c.stop - 4, c.stop + 3)
    both = np.isfinite(matched[r, edge_cols])
    assert both.mean() > 0.5
    np.testing.assert_array_equal(refined[r, edge_cols][both], matched[r, edge_cols][both])
    inside = refined[r.start + 10 : r.stop - 10, c.start + 10 : c.stop - 10]
    assert np.nanmedian(np.abs(inside - 20.6)) < 0.05  # well inside, the square is refined


def test_invalid_pixels_stay_invalid_and_a_field_with_none_valid_is_returned_as_is() -> None:
    frame = _pair(12.3)
    grey = [cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) for img in (frame.left, frame.right)]
    disparity = np.full((HEIGHT, WIDTH), 12.0, np.float32)
    disparity[100:120, 100:140] = np.nan
    out = refine_disparity(*grey, disparity, SubpixelParams())
    assert np.isnan(out[100:120, 100:140]).all() and np.isfinite(out[:100]).all()
    assert np.nanmedian(np.abs(out[INNER] - 12.3)) < 0.05  # from a whole-pixel start as well
    empty = np.full((HEIGHT, WIDTH), np.nan, np.float32)
    assert refine_disparity(*grey, empty, SubpixelParams()) is empty


def test_near_pixels_keep_the_matchers_value() -> None:
    """Over ``max_disparity_px`` (near the car) a refinable start stays as the matcher gave it."""
    frame = _pair(36.3)
    grey = [cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) for img in (frame.left, frame.right)]
    start = np.full((HEIGHT, WIDTH), 36.0, np.float32)
    refined = refine_disparity(*grey, start, SubpixelParams(max_disparity_px=1e9))
    assert np.median(np.abs(refined[30:210, 60:300] - 36.3)) < 0.05  # it would be refined
    np.testing.assert_array_equal(refine_disparity(*grey, start, SubpixelParams(max_disparity_px=32.0)), start)


def test_the_far_band_is_refined_as_in_a_whole_frame() -> None:
    """Only rows holding a far pixel are worked on; what is refined there does not change by it."""
    frame = _pair(12.3)
    grey = [cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) for img in (frame.left, frame.right)]
    disparity = np.full((HEIGHT, WIDTH), 12.0, np.float32)
    disparity[120:] = 40.0  # a near surface below
    banded = refine_disparity(*grey, disparity, SubpixelParams(max_disparity_px=32.0))
    whole = refine_disparity(*grey, disparity, SubpixelParams(max_disparity_px=1e9))
    np.testing.assert_array_equal(banded[120:], disparity[120:])
    assert np.median(np.abs(banded[30:100, 60:300] - 12.3)) < 0.05
    np.testing.assert_allclose(banded[:114], whole[:114], atol=1e-3)  # to the last row the span guard leaves
