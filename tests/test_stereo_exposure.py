"""A dim pair matched as if in daylight (services/stereo_depth/exposure.py): less smear beside depth steps at dusk."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_stereo_depth import BASELINE, BOX, BOX_DEPTH, FX, PLANE_DEPTH, _core, _scene

from common.messages import StereoFrame
from services.stereo_depth.exposure import MAX_GAIN, contrast_gain, stretched

SPAN = 160.0


def _dusk(frame: StereoFrame, seed: int) -> StereoFrame:
    """The pair at 0.3 of its contrast, dark, with sensor noise (the `lowtexture` scenario's look)."""
    rng = np.random.default_rng(seed)

    def dim(image: np.ndarray) -> np.ndarray:
        return np.clip(image * 0.3 + 60.0 + rng.normal(0.0, 3.0, image.shape), 0, 255).astype(np.uint8)

    return dataclasses.replace(frame, left=dim(frame.left), right=dim(frame.right))


def _between_share(disparity: np.ndarray) -> float:
    """Share of the wall's pixels within 12 columns of the box lying between the surfaces (> 0.5 px from both)."""
    rows, cols = BOX
    left_of, right_of = disparity[rows, cols.start - 12 : cols.start], disparity[rows, cols.stop : cols.stop + 12]
    beside = np.concatenate([left_of, right_of], axis=1)
    wall, box = FX * BASELINE / PLANE_DEPTH, FX * BASELINE / BOX_DEPTH
    with np.errstate(invalid="ignore"):
        between = np.isfinite(beside) & (np.abs(beside - wall) > 0.5) & (np.abs(beside - box) > 0.5)
    return float(between.mean())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_dim_pair_smears_less_beside_a_depth_step_when_matched_as_in_daylight(seed: int) -> None:
    dusk = _dusk(_scene(seed), seed)
    _, plain = _core().process(dusk)
    _, lifted = _core(contrast_span=SPAN).process(dusk)
    assert _between_share(plain.disparity) > 0.1  # SGM's smoothness carries the box's disparity across
    assert _between_share(lifted.disparity) < 0.6 * _between_share(plain.disparity)  # 0.14-0.52 x on seeds 0-5
    rows, cols = BOX
    wall = np.ones(plain.disparity.shape, dtype=bool)
    wall[rows, cols.start - 12 : cols.stop + 12] = False
    error = np.abs(lifted.disparity[wall] - FX * BASELINE / PLANE_DEPTH)
    assert np.isfinite(error).mean() > 0.8 and np.nanmedian(error) <= 0.3  # the wall as dense and as sharp


def test_a_pair_spanning_the_contrast_already_is_matched_as_before() -> None:
    rng = np.random.default_rng(4)
    image = rng.integers(0, 256, (60, 80), dtype=np.uint8)
    assert contrast_gain(image, SPAN) == 1.0 and contrast_gain(image, 0.0) == 1.0
    assert stretched(image, 1.0) is image
    frame = _scene(4)  # a textured wall and box spanning 88 grey levels: scaled, yet as sharp
    _, plain = _core(contrast_span=0.0).process(frame)
    _, scaled = _core(contrast_span=SPAN).process(frame)
    wall = FX * BASELINE / PLANE_DEPTH
    for disparity in (plain.disparity, scaled.disparity):
        assert np.nanmedian(np.abs(disparity[:, 40:130] - wall)) <= 0.15


def test_a_dim_image_is_stretched_to_the_span_in_order() -> None:
    rng = np.random.default_rng(5)
    image = rng.integers(40, 100, (60, 80), dtype=np.uint8)
    gain = contrast_gain(image, SPAN)
    assert gain == pytest.approx(SPAN / 58.0, rel=0.05)
    out = stretched(image, gain)
    lo, hi = np.percentile(out, [1, 99])
    assert hi - lo == pytest.approx(SPAN, abs=4.0)
    order = np.argsort(image.ravel(), kind="stable")
    assert np.all(np.diff(out.ravel()[order].astype(np.int16)) >= 0)  # no two levels swap


def test_noise_alone_is_amplified_at_most_max_gain() -> None:
    flat = np.full((60, 80), 90, dtype=np.uint8)
    flat[::2, ::2] = 92  # two levels of noise
    assert contrast_gain(flat, SPAN) == MAX_GAIN
    out = stretched(flat, MAX_GAIN)
    assert int(out.max()) - int(out.min()) == 2 * MAX_GAIN
