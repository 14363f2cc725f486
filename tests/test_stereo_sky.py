"""The sky mask (services/stereo_depth/sky.py): flat image joined to the top row, not what lies under an edge."""

from __future__ import annotations

import numpy as np
from textures import blob_texture

from services.stereo_depth.sky import sky_mask

HEIGHT, WIDTH = 120, 160


def _street(seed: int = 0) -> np.ndarray:
    """Rows 0-39 a noisy flat sky; 40-79 a flat pale wall across the image, with a textured pole
    rising into the sky at columns 70-89; rows 80- textured road, holding a flat patch enclosed by texture."""
    rng = np.random.default_rng(seed)
    image = blob_texture(rng, HEIGHT, WIDTH).astype(np.float32)
    image[:40] = 200.0 + rng.normal(0.0, 1.0, (40, WIDTH, 3))
    image[40:80] = 120.0 + rng.normal(0.0, 1.0, (40, WIDTH, 3))
    image[10:80, 70:90] = blob_texture(rng, 70, 20)
    image[95:110, 20:50] = 90.0
    return image.clip(0, 255).astype(np.uint8)


def test_the_sky_is_found_but_not_the_flat_wall_under_its_horizontal_edge() -> None:
    sky = sky_mask(_street(), 5, 8.0)
    assert sky[:36, :66].mean() > 0.97 and sky[:36, 94:].mean() > 0.97
    assert not sky[44:, :].any()  # the wall meets the sky along a row: no gradient across, but one down
    assert not sky[12:36, 72:88].any()  # the pole's texture


def test_a_flat_patch_enclosed_by_texture_is_not_sky() -> None:
    sky = sky_mask(_street(), 5, 8.0)
    assert not sky[95:110, 20:50].any()


def test_an_image_textured_along_its_top_row_has_no_sky() -> None:
    image = blob_texture(np.random.default_rng(3), HEIGHT, WIDTH)
    assert not sky_mask(image, 5, 8.0).any()


def _gantry(seed: int = 0) -> np.ndarray:
    """Rows 0-59 a noisy flat sky; a textured bar (rows 20-29) on two posts (columns 20-29, 130-139)
    down to the textured road from row 60, which holds a flat patch of the sky's own colour."""
    rng = np.random.default_rng(seed)
    image = blob_texture(rng, HEIGHT, WIDTH).astype(np.float32)
    image[:60] = 200.0 + rng.normal(0.0, 1.0, (60, WIDTH, 3))
    image[20:30, 20:140] = blob_texture(rng, 10, 120)
    image[20:60, 20:30] = blob_texture(rng, 40, 10)
    image[20:60, 130:140] = blob_texture(rng, 40, 10)
    image[95:110, 60:100] = 200.0
    return image.clip(0, 255).astype(np.uint8)


def test_sky_seen_under_a_gantry_is_sky_when_gaps_are_asked_for() -> None:
    image = _gantry()
    assert not sky_mask(image, 5, 8.0)[36:56, 36:124].any()  # not joined to the top row
    sky = sky_mask(image, 5, 8.0, image, 10.0)
    assert sky[36:56, 36:124].mean() > 0.97
    assert not sky[22:28, 36:124].any()  # the bar
    assert not sky[95:110, 60:100].any()  # the sky's colour, but lower than the open sky reaches


def test_a_gap_of_another_colour_is_not_sky() -> None:
    image = _gantry()
    image[32:60, 30:130] = 150
    assert not sky_mask(image, 5, 8.0, image, 10.0)[36:56, 36:124].any()


def test_a_gap_enclosed_by_one_surface_keeps_its_points() -> None:
    """A pale patch of a facade looks like the sky beside it, but the facade around it is one depth."""
    image = _gantry()
    disparity = np.full((HEIGHT, WIDTH), 2.0, dtype=np.float32)  # the far road and horizon
    disparity[20:60, 20:140] = 10.0  # the gantry, and what SGM carried down into the gap under it ...
    disparity[45:60, 30:130] = 2.0  # ... and up from the horizon
    assert sky_mask(image, 5, 8.0, image, 10.0, disparity)[36:56, 36:124].mean() > 0.97
    disparity[:] = 10.0  # a wall all around: the gap is part of it
    assert not sky_mask(image, 5, 8.0, image, 10.0, disparity)[36:56, 36:124].any()
