"""A dim pair matched with SGM's penalties scaled to its contrast (services/stereo_depth/exposure.py)."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
from test_stereo_depth import BASELINE, FX, HEIGHT, PLANE_DEPTH, WIDTH, _calib, _core
from textures import blob_texture

from common.messages import StereoFrame
from services.stereo_depth.exposure import MAX_GAIN, contrast_gain

SPAN = 160.0
POST_D, POST_W = 40, 8  # four posts 8 px wide at 40 px of disparity, before the wall at 32.5 px
POSTS = (100, 160, 220, 280)  # their left columns in the left image


def _posts(seed: int) -> StereoFrame:
    """Textured posts standing before a textured wall, rows 40-199."""
    rng = np.random.default_rng(seed)
    wall, post = blob_texture(rng, HEIGHT, WIDTH + 32), blob_texture(rng, HEIGHT, WIDTH + POST_D)
    map_x = np.broadcast_to(
        np.arange(WIDTH, dtype=np.float32) + np.float32(FX * BASELINE / PLANE_DEPTH), (HEIGHT, WIDTH)
    )
    map_y = np.broadcast_to(np.arange(HEIGHT, dtype=np.float32)[:, None], (HEIGHT, WIDTH))
    right = cv2.remap(wall, np.ascontiguousarray(map_x), np.ascontiguousarray(map_y), cv2.INTER_LINEAR)
    left = wall[:, :WIDTH].copy()
    for c in POSTS:
        left[40:200, c : c + POST_W] = post[40:200, c : c + POST_W]
        right[40:200, c - POST_D : c - POST_D + POST_W] = post[40:200, c : c + POST_W]
    return StereoFrame(frame_id=1, stamp_ns=1, left=left, right=right, calib=_calib())


def _dusk(frame: StereoFrame, seed: int) -> StereoFrame:
    """The pair at 0.3 of its contrast, dark, blurred, with sensor noise (the `lowtexture` scenario's look)."""
    rng = np.random.default_rng(seed + 100)

    def dim(image: np.ndarray) -> np.ndarray:
        blurred = cv2.GaussianBlur(image.astype(np.float32) * 0.3 + 60.0, (0, 0), 0.8)
        return np.clip(blurred + rng.normal(0.0, 3.0, image.shape), 0, 255).astype(np.uint8)

    return dataclasses.replace(frame, left=dim(frame.left), right=dim(frame.right))


def _on_the_posts(disparity: np.ndarray) -> float:
    """Share of the posts' inner pixels given the posts' disparity (within 1 px)."""
    pixels = np.concatenate([disparity[40:200, c + 1 : c + POST_W - 1] for c in POSTS], axis=1)
    with np.errstate(invalid="ignore"):
        return float(np.mean(np.abs(pixels - POST_D) < 1.0))


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_posts_before_a_wall_at_dusk_keep_their_disparity_when_the_penalties_follow_the_contrast(seed: int) -> None:
    daylight = _posts(seed)
    dusk = _dusk(daylight, seed)
    assert contrast_gain(cv2.cvtColor(dusk.left, cv2.COLOR_RGB2GRAY), SPAN) > 2.0
    fixed = _on_the_posts(_core().process(dusk)[1].disparity)  # test_stereo_depth's helper: contrast_span 0
    scaled = _on_the_posts(_core(contrast_span=SPAN).process(dusk)[1].disparity)
    seen_by_day = _on_the_posts(_core().process(daylight)[1].disparity)
    assert fixed < 0.3 < seen_by_day  # fixed penalties smooth the posts into the wall
    assert scaled > fixed + 0.15


def _wide(frame: StereoFrame) -> StereoFrame:
    """The pair in grey, spread over the whole grey range, as a daylight camera's."""

    def spread(image: np.ndarray) -> np.ndarray:
        grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32)
        lo, hi = np.percentile(grey, (0.5, 99.5))
        wide = ((grey - lo) * (255.0 / (hi - lo))).clip(0, 255).astype(np.uint8)
        return cv2.cvtColor(wide, cv2.COLOR_GRAY2RGB)

    return dataclasses.replace(frame, left=spread(frame.left), right=spread(frame.right))


def test_a_pair_spanning_the_contrast_already_is_matched_bit_for_bit_as_before() -> None:
    daylight = _wide(_posts(4))
    assert contrast_gain(cv2.cvtColor(daylight.left, cv2.COLOR_RGB2GRAY), SPAN) == 1.0
    core = _core(contrast_span=SPAN)
    core.process(_dusk(_posts(4), 4))  # a dim pair first: its penalties must not outlive it
    after_dusk = core.process(daylight)[1].disparity
    never_scaled = _core().process(daylight)[1].disparity
    assert np.array_equal(after_dusk, never_scaled, equal_nan=True)


def test_the_gain_is_the_span_over_the_images_and_at_most_max_gain() -> None:
    rng = np.random.default_rng(5)
    image = rng.integers(40, 100, (60, 80), dtype=np.uint8)
    assert contrast_gain(image, SPAN) == pytest.approx(SPAN / 58.0, rel=0.05)
    flat = np.full((60, 80), 90, dtype=np.uint8)
    flat[::2, ::2] = 92  # two levels of noise
    assert contrast_gain(flat, SPAN) == MAX_GAIN
