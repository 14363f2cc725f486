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


def _slot() -> tuple[np.ndarray, np.ndarray]:
    """The street with a second textured post at columns 100-109: a slot of sky 10 columns wide
    between it and the pole; the pole 10 px of disparity, the post 4 (farther), what SGM carried
    into the sky beside them a value between."""
    image = _street()
    image[10:80, 100:110] = blob_texture(np.random.default_rng(5), 70, 10)
    disparity = np.full((HEIGHT, WIDTH), np.nan, dtype=np.float32)
    disparity[10:80, 70:90] = 10.0
    disparity[10:80, 100:110] = 4.0
    disparity[10:40, 90:100] = 7.0
    disparity[10:40, 66:70] = 10.0  # the pole's fattening into the open sky
    return image, disparity


def test_the_fringe_in_a_slot_between_two_depths_is_sky_and_beside_open_sky_it_is_not() -> None:
    """The columns of sky beside an edge are not flat over the window, so they stay out of the mask
    and keep what SGM carried in; in a slot between two depths that is a value in the air between
    them, beside one edge against open sky the edge's own (a walker's head)."""
    image, disparity = _slot()
    plain = sky_mask(image, 5, 8.0, image, 10.0, disparity)
    assert not plain[12:36, 90:92].any() and not plain[12:36, 98:100].any()  # the slot's sides
    fringe = sky_mask(image, 5, 8.0, image, 10.0, disparity, fringe_px=3)
    assert fringe[12:36, 90:100].all()
    assert not fringe[12:36, 67:70].any()  # beside the pole, on the open sky's side
    assert not fringe[12:40, 70:90].any() and not fringe[12:40, 100:110].any()  # the pole and the post
    assert not fringe[40:, :].any()  # the wall under the sky: another colour
    grown = fringe & ~plain
    assert grown.any() and (image[grown] > 190).all()  # only the sky's colour


def test_a_slot_between_parts_of_one_surface_keeps_its_fringe() -> None:
    image, disparity = _slot()
    disparity[10:80, 100:110] = 10.0  # the post as near as the pole: a gantry's two legs
    disparity[10:40, 90:100] = 10.0
    fringe = sky_mask(image, 5, 8.0, image, 10.0, disparity, fringe_px=3)
    assert not fringe[12:36, 90:92].any() and not fringe[12:36, 98:100].any()


def test_a_fringe_of_another_colour_keeps_its_points() -> None:
    """A pale edge beside the sky (here two columns of the pole's side, 40 grey levels darker than
    the sky) is the object's, not the sky's."""
    image, disparity = _slot()
    image[10:40, 90:92] = 160
    fringe = sky_mask(image, 5, 8.0, image, 10.0, disparity, fringe_px=3)
    assert not fringe[12:36, 90:92].any()
    assert fringe[12:36, 93:100].all()  # the rest of the slot as before


def _horizon() -> tuple[np.ndarray, np.ndarray]:
    """Rows 0-39 a noisy flat sky over textured ground, a textured post (columns 70-89) rising to row 10;
    the ground far (2 px of disparity), the post near (10). Along the rows just above the horizon SGM
    carried the post's 10 sideways (columns 40-119); farther out they hold the horizon's own 2, and
    above the post's top its own 10 (a walker's head)."""
    rng = np.random.default_rng(0)
    image = blob_texture(rng, HEIGHT, WIDTH).astype(np.float32)
    image[:40] = 200.0 + rng.normal(0.0, 1.0, (40, WIDTH, 3))
    image[10:40, 70:90] = blob_texture(rng, 30, 20)
    disparity = np.full((HEIGHT, WIDTH), 2.0, dtype=np.float32)
    disparity[30:40, 40:120] = 10.0
    disparity[:, 70:90] = 10.0
    return image.clip(0, 255).astype(np.uint8), disparity


def test_the_sky_over_the_horizon_holding_a_post_s_depth_is_sky_and_over_a_head_it_is_not() -> None:
    image, disparity = _horizon()
    plain = sky_mask(image, 5, 8.0, image, 10.0, disparity, fringe_px=2)
    assert not plain[38:40, 40:66].any() and not plain[38:40, 94:120].any()  # unflat: the horizon's edge
    under = sky_mask(image, 5, 8.0, image, 10.0, disparity, fringe_px=2, underside_px=4)
    assert under[36:40, 40:66].all() and under[36:40, 94:120].all()
    assert not under[38:40, :36].any() and not under[38:40, 124:].any()  # the horizon's own depth
    grown = under & ~plain
    assert not under[10:40, 70:90].any() and not grown[:10, 66:94].any()  # the post, and the rows over its top
    assert not under[40:].any() and (image[grown] > 190).all()


def _narrow_gap(pole_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows 0-59 a noisy flat sky; a textured bar (rows 20-29, columns 20-139) on a post (columns
    20-29), and a thin pole at columns 56-59 behind it, at ``pole_px`` against the bar's 11.5: a gap
    of sky 26 columns wide between post and pole, into which SGM carried each side's disparity, over
    ground at the bar's depth."""
    rng = np.random.default_rng(1)
    image = blob_texture(rng, HEIGHT, WIDTH).astype(np.float32)
    image[:60] = 200.0 + rng.normal(0.0, 1.0, (60, WIDTH, 3))
    image[20:30, 20:140] = blob_texture(rng, 10, 120)
    image[20:60, 20:30] = blob_texture(rng, 40, 10)
    image[20:60, 56:60] = blob_texture(rng, 40, 4)
    disparity = np.full((HEIGHT, WIDTH), 11.0, dtype=np.float32)  # the ground at the gantry's foot
    disparity[:60] = np.nan
    disparity[20:30, 20:140] = disparity[20:60, 20:43] = 11.5
    disparity[30:60, 43:60] = pole_px
    return image.clip(0, 255).astype(np.uint8), disparity


def test_a_narrow_gap_between_two_depths_is_sky_though_its_border_seems_one_surface() -> None:
    """The ring test takes 11.5 and 10.0 px for one surface seen askew; row by row, the gap's two ends differ."""
    image, disparity = _narrow_gap(10.0)
    sky = sky_mask(image, 5, 8.0, image, 10.0, disparity)
    assert sky[33:57, 33:53].mean() > 0.97
    assert not sky[22:28, 36:124].any() and not sky[22:60, 21:29].any()  # the bar and the post
    image, disparity = _narrow_gap(11.5)  # the pole as near as the post: one surface
    assert not sky_mask(image, 5, 8.0, image, 10.0, disparity)[33:57, 33:53].any()


def test_a_gap_ending_a_row_or_two_below_the_open_sky_is_sky() -> None:
    """The window that judges flatness ends the open sky a little higher where texture meets it."""
    image = _gantry()
    image[56:60, :20] = blob_texture(np.random.default_rng(4), 4, 20)
    image[56:60, 140:] = blob_texture(np.random.default_rng(5), 4, 20)
    disparity = np.full((HEIGHT, WIDTH), 2.0, dtype=np.float32)
    disparity[20:60, 20:140] = 10.0
    disparity[45:60, 30:130] = 2.0
    sky = sky_mask(image, 5, 8.0, image, 10.0, disparity)
    assert sky[36:56, 36:124].mean() > 0.97


def test_a_gap_is_judged_by_what_lies_beyond_its_fringe() -> None:
    """SGM carried the bar's disparity into the whole gap, its unflat fringe too (the 3 px beside each
    edge); only past the fringe, at the horizon under it, does another depth show."""
    image = _gantry()
    disparity = np.full((HEIGHT, WIDTH), 2.0, dtype=np.float32)  # the far road and horizon
    disparity[20:60, 20:140] = 10.0  # the gantry, and the gap under it to the horizon
    assert sky_mask(image, 5, 8.0, image, 10.0, disparity)[36:56, 36:124].mean() > 0.97
