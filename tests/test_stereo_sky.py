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
