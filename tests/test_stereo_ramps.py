"""Ramp pixels across a depth step (services/stereo_depth/ramps.py): hand-made rows, the cloud, a rendered frame."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from common.config import Config
from common.config_loading import load_config
from common.errors import ConfigError
from common.geometry import camera_to_vehicle
from common.messages import Calibration, StereoFrame
from common.scenarios.catalogue import build
from common.scenarios.render import Renderer, Rig
from common.scenarios.simulate import FRAME_RATE_HZ
from services.stereo_depth import StereoDepth
from services.stereo_depth.ramps import RampFilter
from services.stereo_depth.reproject import Reprojector, VolumeCrop


def _row(*runs: tuple[float, int]) -> np.ndarray:
    """One image row (1 x N float32) made of runs of (disparity, columns)."""
    return np.concatenate([np.full(n, d, np.float32) for d, n in runs])[None, :]


def _marks(mask: np.ndarray) -> str:
    return "".join("x" if m else "." for m in mask[0])


def test_pixels_between_two_plateaus_are_dropped_and_both_surfaces_kept() -> None:
    """A pole at 12 px before a wall at 10 px, with the matcher's three in-between columns."""
    row = np.concatenate([_row((12.0, 12)), np.array([[11.5, 11.0, 10.5]], np.float32), _row((10.0, 12))], axis=1)
    assert _marks(RampFilter().mask(row)) == "." * 12 + "xxx" + "." * 12
    # a pixel within the margin of a plateau belongs to that surface
    row[0, 12] = 11.9
    assert _marks(RampFilter().mask(row)) == "." * 13 + "xx" + "." * 12


def test_a_surface_seen_at_a_slant_is_kept() -> None:
    """A wall 3 m beside a 0.4 m baseline rig: 0.13 px per column, 1.3 px between the plateaus."""
    slope = (20.0 + 0.13 * np.arange(60, dtype=np.float32))[None, :]
    assert not RampFilter().mask(slope).any()
    assert RampFilter(flat_share=1.0).mask(slope)[0, 10:-10].all()  # what the flatness test is for


def test_a_step_smaller_than_the_limit_and_noisy_plateaus() -> None:
    assert not RampFilter().mask(_row((10.6, 12), (10.3, 2), (10.0, 12))).any()  # 0.6 px: one slanted surface
    rng = np.random.default_rng(3)
    row = _row((12.0, 20), (11.0, 2), (10.0, 20)) + rng.normal(0.0, 0.02, (1, 42)).astype(np.float32)
    assert _marks(RampFilter().mask(row)) == "." * 20 + "xx" + "." * 20


def test_missing_disparities_never_make_a_step() -> None:
    row = _row((12.0, 12), (11.0, 2), (np.nan, 12))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no all-NaN mean warnings either
        assert not RampFilter().mask(row).any()
        assert not RampFilter().mask(np.full((4, 6), 11.0, np.float32)).any()  # narrower than both plateaus
    out = RampFilter().apply(_row((12.0, 12), (11.0, 2), (10.0, 12)))
    assert np.isnan(out[0, 12:14]).all() and np.isfinite(out[0, :12]).all() and np.isfinite(out[0, 14:]).all()


@pytest.mark.parametrize(
    "setting",
    ["ramp_reach_px=0", "ramp_width_px=0", "ramp_margin_px=-0.1", "ramp_flat_share=-1", "ramp_snap_ratio=1.5"],
)
def test_bad_ramp_settings_are_refused(setting: str) -> None:
    with pytest.raises(ConfigError):
        StereoDepth.from_config(load_config(sets=["stereo.ramp_step_px=1.0", f"stereo.{setting}"]))


def _step_cloud(ramps: RampFilter, image: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """A surface at 10 m before one at 15 m, with three ramp columns between them, reprojected by hand
    without and with ``ramps``: both clouds' points and the two surfaces' ranges."""
    fx, baseline = 600.0, 0.4
    disparity = np.tile(_row((24.0, 40), (22.0, 1), (20.0, 1), (18.0, 1), (16.0, 40)), (60, 1))
    frame_calib = Calibration(
        fx=fx, fy=fx, cx=41.5, cy=30.0, baseline=baseline, width=83, height=60, cam_to_vehicle=camera_to_vehicle(1.5)
    )
    crop = VolumeCrop.from_config(Config().volume, 10.0)
    plain = Reprojector(crop, 0.5).points(disparity, image, frame_calib)[0]
    filtered = Reprojector(crop, 0.5, ramps=ramps).points(disparity, image, frame_calib)[0]
    return plain, filtered, fx * baseline / 24.0, fx * baseline / 16.0


def test_the_cloud_leaves_out_ramp_points_but_keeps_both_surfaces() -> None:
    """The ramp columns' points lie between the two surfaces and are gone."""
    plain, ramps, near, far = _step_cloud(RampFilter(), np.zeros((60, 83, 3), np.uint8))
    between = (plain[:, 0] > near + 0.1) & (plain[:, 0] < far - 0.1)
    assert between.sum() == 3 * 60
    assert len(ramps) == len(plain) - 3 * 60
    assert not ((ramps[:, 0] > near + 0.1) & (ramps[:, 0] < far - 0.1)).any()


def test_on_a_rendered_street_the_dropped_pixels_are_mostly_the_matchers_misplaced_ones() -> None:
    """Synthetic urban, seed 3, frame 12 (poles before kiosks and walls): the published disparity is untouched,
    and the pixels left out of the cloud are far more often over 1 px wrong than pixels are on average."""
    rig = Rig()
    rendered = Renderer(build("urban", 3), rig).render(12 / FRAME_RATE_HZ, np.random.default_rng([3, 12]))
    frame = StereoFrame(frame_id=12, stamp_ns=0, left=rendered.left, right=rendered.right, calib=rig.calibration())
    plain_cloud, plain = StereoDepth.from_config(load_config(sets=["stereo.ramp_step_px=0"])).process(frame)
    leave_out = ["stereo.ramp_step_px=1.0", "stereo.ramp_snap_ratio=0", "stereo.ramp_flat_share=0.15"]
    cloud, disp = StereoDepth.from_config(load_config(sets=leave_out)).process(frame)
    assert np.array_equal(disp.disparity, plain.disparity, equal_nan=True)
    estimate, truth = np.asarray(disp.disparity), rendered.disparity
    dropped = RampFilter().mask(estimate)
    both = np.isfinite(estimate) & np.isfinite(truth)
    wrong = both & (np.abs(estimate - truth) > 1.0)
    assert 0.002 * both.sum() < dropped.sum() < 0.05 * both.sum()
    share_dropped = (dropped & wrong).sum() / (dropped & both).sum()
    assert share_dropped > 5 * wrong.sum() / both.sum()
    assert len(cloud.points) < len(plain_cloud.points)


GREY, RED, PINK = (120, 120, 120), (200, 30, 30), (160, 75, 75)


def _image(*runs: tuple[tuple[int, int, int], int]) -> np.ndarray:
    """One image row (1 x N x 3 uint8) made of runs of (colour, columns)."""
    return np.concatenate([np.tile(np.array(c, np.uint8), (n, 1)) for c, n in runs])[None, :, :]


def test_snapping_moves_a_ramp_pixel_onto_the_surface_of_its_colour() -> None:
    """A red pole at 12 px before a grey wall at 10 px; the three in-between columns are grey, red and
    a colour halfway between: the grey one joins the wall, the red one the pole, the third stays."""
    row = np.concatenate([_row((12.0, 12)), np.array([[11.5, 11.0, 10.5]], np.float32), _row((10.0, 12))], axis=1)
    image = _image((RED, 12), (RED, 1), (PINK, 1), (GREY, 1), (GREY, 12))
    snapped = RampFilter(flat_share=0.0, snap_ratio=0.5).apply(row, image)
    np.testing.assert_array_equal(snapped[0, 12:15], [12.0, 11.0, 10.0])
    np.testing.assert_array_equal(snapped[0, :12], row[0, :12])  # both surfaces untouched
    np.testing.assert_array_equal(snapped[0, 15:], row[0, 15:])
    assert np.isnan(RampFilter().apply(row)[0, 12:15]).all()  # without snapping they are left out
    with pytest.raises(ConfigError, match="needs the image"):
        RampFilter(snap_ratio=0.5).apply(row)


def test_snapping_keeps_every_point_and_empties_the_space_between() -> None:
    """Reprojected: with snapping the cloud has as many points as without, none between the surfaces."""
    image = np.tile(_image((RED, 42), (GREY, 41)), (60, 1, 1))
    plain, snapped, near, far = _step_cloud(RampFilter(flat_share=0.0, snap_ratio=0.5), image)
    assert len(snapped) == len(plain)
    assert not ((snapped[:, 0] > near + 0.1) & (snapped[:, 0] < far - 0.1)).any()
    cloud_cfg = load_config(sets=["stereo.ramp_step_px=1.0", "stereo.ramp_snap_ratio=0.5", "stereo.ramp_flat_share=0"])
    assert StereoDepth.from_config(cloud_cfg).reprojector.ramps == RampFilter(flat_share=0.0, snap_ratio=0.5)


def test_snapping_a_frame_narrower_than_the_plateaus_changes_nothing() -> None:
    tiny = np.full((4, 1), 11.0, np.float32)  # one column: no run of three to average a colour over
    out = RampFilter(snap_ratio=0.5).apply(tiny, np.zeros((4, 1, 3), np.uint8))
    np.testing.assert_array_equal(out, tiny)


def test_snapping_matches_a_pixel_by_pixel_reading_of_the_rule() -> None:
    """The colour test looks only at ramp pixels; each must move exactly as the rule read pixel by pixel says."""
    rng = np.random.default_rng(5)
    disparity = (rng.random((30, 60)) * 3 + 10).astype(np.float32)
    disparity[:, 25:35] += 3.0
    disparity[rng.random(disparity.shape) < 0.05] = np.nan
    image = (rng.random((30, 60, 3)) * 255).astype(np.uint8)
    f = RampFilter(flat_share=0.0, snap_ratio=0.3)
    ramp, left, right = f._ramp(disparity)
    expected = disparity.copy()
    span = f.reach + f.width - 1

    def off(r: int, c: int, first: int) -> float:  # L1 colour distance to the run of columns from ``first``
        return float(np.abs(image[r, c].astype(np.float32) - image[r, first : first + f.width].mean(axis=0)).sum())

    for r, c in zip(*np.nonzero(ramp), strict=True):
        near_left, near_right = off(r, c, c - span), off(r, c, c + f.reach)
        if near_left < f.snap_ratio * near_right:
            expected[r, c] = left[r, c]
        elif near_right < f.snap_ratio * near_left:
            expected[r, c] = right[r, c]
    assert ramp.sum() > 50
    np.testing.assert_allclose(f.apply(disparity, image), expected, rtol=0, atol=1e-5)


def test_snapping_is_on_by_default() -> None:
    """Session 46 measured it on 61 runs and kept it (docs/results/voxel.md)."""
    ramps = StereoDepth.from_config(load_config()).reprojector.ramps
    assert ramps == RampFilter(step_px=1.0, flat_share=0.0, snap_ratio=0.3)
