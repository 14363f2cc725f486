"""The sky: flat image joined to the top row, where no honest disparity exists.

SGM's smoothness carries a near object's disparity into the flat sky beside it, and both views
can agree on the carried value, so a left-right check keeps it. Measured on synthetic `urban`
seed 7: a band of sky above a wall's top edge took a pole's disparity and joined the pole to the
wall 2.3 m behind it in one cluster.

A pixel is sky when a path of flat pixels joins it to the image's top row. Flat means little
gradient in either direction: the matcher's own texture test looks only across (that is what
matching sees), and a horizontal edge, such as a hedge's top against a pale sky or a walker's
head, has no gradient across, so the sky would flood through it into whatever flat surface lies
below.

Sky also shows through gaps that do not reach the top row: under a gantry or a height barrier,
between a bridge and the horizon. SGM carries the bar's disparity down into that flat strip,
and the strip's points hang under the bar as a false obstacle (synthetic `hanging` seed 7: the
strip under a barrier at 17 m became a 255-voxel cluster 1.6-2.7 m up, over the lane). With
``gap_colour`` > 0, a flat region not joined to the top row is sky too when its mean colour is
within ``gap_colour`` grey levels (every channel) of the open sky's on the same rows, and it
reaches no lower than the open sky does (a pale wall or a truck's side stands on the ground,
below the horizon the open sky stops at), and when its border holds two depths (``_gaps``); it
then takes the few pixels of its colour around it too (``_add_grown``). Held-out `hanging` seeds
7-10: the overhang's span within +-0.25 m in 87-100 % of frames, against 67-98 % without
(docs/results/voxel.md, "Session 27").
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from services.stereo_depth.sgbm import Image

#: flat regions smaller than this (pixels) are never taken for sky seen through a gap.
MIN_GAP_PX = 25
#: the fringe is sky only in a slot: a run of the sky's colour along a row at most this wide between two
#: surfaces, whose disparities (the pixels either side) differ by more than ``SLOT_STEP_PX``. Beside
#: one edge against open sky, or between two parts of one surface, SGM carries the edge's own
#: disparity, and a walker's head or a gantry's sign hangs together by it (``_add_fringe``).
SLOT_PX, SLOT_STEP_PX = 24, 1.0


def sky_mask(
    image: Image,
    window: int,
    max_gradient: float,
    colour: Image | None = None,
    gap_colour: float = 0.0,
    disparity: npt.NDArray[np.float32] | None = None,
    fringe_px: int = 0,
    underside_px: int = 0,
) -> npt.NDArray[np.bool_]:
    """Pixels joined to the top row through pixels whose mean |gradient| (window square) is under ``max_gradient``;
    with ``colour`` (the RGB image) and ``gap_colour`` > 0, also flat regions of the open sky's colour (above),
    with ``fringe_px`` > 0 the pixels of its colour that far around the open sky (``_add_fringe``), and with
    ``underside_px`` > 0 and ``disparity`` those that far under it holding another depth than what lies
    below them (``_add_underside``)."""
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    gradient = np.abs(cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3)) + np.abs(cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3))
    flat = (cv2.blur(gradient, (window, window)) < np.float32(max_gradient)).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(flat, connectivity=4)
    top = np.unique(labels[0][flat[0] > 0])
    if not top.size:
        return np.zeros(grey.shape, dtype=bool)
    is_sky = np.zeros(count, dtype=bool)
    is_sky[top] = True
    sky = is_sky[labels]
    if gap_colour > 0.0 and colour is not None and colour.ndim == 3:
        gaps = _gaps(labels, stats, is_sky, sky, colour, gap_colour, disparity, window)
        if gaps.any():
            _add_grown(sky, labels, stats, gaps, colour, gap_colour, window // 2 + 1)
        if fringe_px > 0:
            _add_fringe(sky, colour, gap_colour, fringe_px, disparity)
        if underside_px > 0 and disparity is not None:
            _add_underside(sky, colour, gap_colour, underside_px, disparity)
    return sky


def _add_fringe(
    sky: npt.NDArray[np.bool_],
    colour: Image,
    tolerance: float,
    reach: int,
    disparity: npt.NDArray[np.float32] | None = None,
) -> None:
    """Add to ``sky`` the pixels up to ``reach`` pixels around it within ``tolerance`` grey levels (every
    channel) of the sky's mean colour on their row, where they lie in a slot (``SLOT_PX``).

    Flatness is judged over a window, so the columns of sky beside a building's edge or a pole are
    not flat and stayed out; they hold the disparity SGM carried in from the edge, and where two
    edges at two depths face each other across a narrow slot of sky, a value between them:
    synthetic `slope` seed 7's sky between a building's corner and a pole behind it, and between a
    wall's end and a post, became clusters 2 m up, in the air (docs/results/voxel.md, "Session
    69"). Taken everywhere, the fringe cost walkers their heads against the sky and split gantries.
    """
    rows = np.flatnonzero(sky.any(axis=1))
    if not rows.size:
        return
    top, bottom = max(int(rows[0]) - reach, 0), min(int(rows[-1]) + reach + 1, sky.shape[0])
    band, patch = sky[top:bottom], colour[top:bottom]
    near = cv2.dilate(band.view(np.uint8), np.ones((3, 3), np.uint8), iterations=reach).view(bool) & ~band
    ys, xs = np.nonzero(near)
    if not ys.size:
        return
    reference = _row_colours(band, patch)
    alike = np.all(np.abs(patch[ys, xs] - reference[ys]) <= tolerance, axis=1)
    fringe = np.zeros_like(band)
    fringe[ys[alike], xs[alike]] = True
    band |= fringe & _in_slot(band | fringe, SLOT_PX, None if disparity is None else disparity[top:bottom])


def _add_underside(
    sky: npt.NDArray[np.bool_], colour: Image, tolerance: float, reach: int, disparity: npt.NDArray[np.float32]
) -> None:
    """Add to ``sky`` the pixels up to ``reach`` rows under it, joined to it down their column through
    pixels of the sky's colour on their row (within ``tolerance``), whose disparity is not that of the
    first other pixel below them (within ``SLOT_STEP_PX``; a hole in the open sky has none).

    The horizon is an edge along the row: the rows of sky just above it are not flat over the
    window, and along them there is nothing to match, so SGM carries a post's disparity sideways
    into them, 50 px and more: synthetic `hanging` seeds 9 and 10 hung them under their signs as
    a second cluster, 1.4-1.9 m up over the lane. Above a walker's head, a car's roof or a bar, the
    same rows hold what lies below them, and stay.
    """
    rows = np.flatnonzero(sky.any(axis=1))
    if not rows.size:
        return
    top, bottom = int(rows[0]), min(int(rows[-1]) + reach + 2, sky.shape[0])
    band, patch, values = sky[top:bottom], colour[top:bottom], disparity[top:bottom]
    # the colour is read only where a pixel could be joined: within reach rows under the sky
    near = np.zeros_like(band)
    for k in range(1, reach + 1):
        near[k:] |= band[:-k]
    near &= ~band
    ys, xs = np.nonzero(near)
    if not ys.size:
        return
    alike = np.zeros_like(band)
    alike[ys, xs] = np.all(np.abs(patch[ys, xs] - _row_colours(band, patch)[ys]) <= tolerance, axis=1)
    under = np.zeros_like(band)
    step = band
    for _ in range(reach):
        step = np.vstack([np.zeros_like(step[:1]), step[:-1] & alike[1:]])
        under |= step
    ys, xs = np.nonzero(under)
    if not ys.size:
        return
    # the disparity of the first pixel below each that is neither under the sky nor the sky (a run of
    # them is at most ``reach`` long)
    below = np.full(ys.size, np.nan, dtype=np.float32)
    searching = np.ones(ys.size, dtype=bool)
    for k in range(1, reach + 2):
        row = np.minimum(ys + k, len(band) - 1)
        end = searching & (~under[row, xs] | (ys + k >= len(band)))
        inside = end & (ys + k < len(band)) & ~band[row, xs]
        below[inside] = values[row[inside], xs[inside]]
        searching &= ~end
    with np.errstate(invalid="ignore"):
        same = np.abs(values[ys, xs] - below) <= SLOT_STEP_PX
    band[ys[~same], xs[~same]] = True


def _in_slot(
    mask: npt.NDArray[np.bool_], width: int, disparity: npt.NDArray[np.float32] | None = None
) -> npt.NDArray[np.bool_]:
    """Pixels of ``mask`` in a run along their row of at most ``width`` pixels, with no end at an image side
    (and with ``disparity``, whose two bounding pixels are not one depth; one with no value is another)."""
    h, w = mask.shape
    starts = mask.copy()
    starts[:, 1:] &= ~mask[:, :-1]
    ids = np.cumsum(starts.ravel()).reshape(h, w) * mask
    lengths = np.bincount(ids.ravel())
    lengths[0] = 0
    open_ends = np.unique(np.concatenate([ids[:, 0], ids[:, -1]]))
    short = lengths <= width
    short[open_ends] = False
    short[0] = False
    if disparity is not None:
        rows, first = np.nonzero(starts)
        last = first + lengths[1:] - 1
        left = disparity[rows, np.clip(first - 1, 0, w - 1)]
        right = disparity[rows, np.clip(last + 1, 0, w - 1)]
        with np.errstate(invalid="ignore"):
            one = np.abs(left - right) <= SLOT_STEP_PX
        short[1:] &= ~one
    return short[ids]


def _row_colours(band: npt.NDArray[np.bool_], patch: Image) -> npt.NDArray[np.float32]:
    """The open sky's mean colour on each row of ``band``; a row with none takes the nearest row's (the
    rows just under the sky's lowest, its lowest row's). The sky's colour changes from the top of the
    image to the horizon, so each row is held to its own."""
    count = band.sum(axis=1, dtype=np.float32)
    with np.errstate(invalid="ignore", divide="ignore"):  # rows with no sky: NaN until filled
        reference = np.einsum("rc,rck->rk", band.astype(np.float32), patch.astype(np.float32)) / count[:, None]
    return np.where(np.isfinite(reference), reference, _nearest_row(reference))


def _nearest_row(reference: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    """Each row's value from the nearest row that has one (NaN where none has)."""
    known = np.flatnonzero(np.isfinite(reference[:, 0]))
    if not known.size:
        return reference
    index = np.searchsorted(known, np.arange(len(reference)))
    below, above = known[np.clip(index, 0, len(known) - 1)], known[np.clip(index - 1, 0, len(known) - 1)]
    rows = np.arange(len(reference))
    nearest = np.where(np.abs(below - rows) <= np.abs(rows - above), below, above)
    return reference[nearest]


#: a ring this wide (pixels) around a region is its border; its disparities' 10th and 90th
#: percentiles within this ratio (plus half a pixel) are one surface's. The ring must reach past the
#: region's own unflat fringe (up to 3 px with a 5 px window), which holds what SGM carried in from one
#: side: 3 px wide, hanging seed 13's sky under a sign read as one surface with the sign (session 70).
RING_PX, ONE_DEPTH_RATIO = 5, 1.25


def _one_depth_around(
    labels: npt.NDArray[np.int32], c: int, box: npt.NDArray[np.int32], disparity: npt.NDArray[np.float32]
) -> bool:
    """Whether the finite disparities on the border of component ``c`` (box: x, y, w, h) are one surface's."""
    x, y, w, h = (int(v) for v in box[0:4])
    y0, x0 = max(y - RING_PX, 0), max(x - RING_PX, 0)
    own = (labels[y0 : y + h + RING_PX, x0 : x + w + RING_PX] == c).view(np.uint8)
    ring = cv2.dilate(own, np.ones((3, 3), np.uint8), iterations=RING_PX).view(bool) & ~own.view(bool)
    values = disparity[y0 : y + h + RING_PX, x0 : x + w + RING_PX][ring]
    values = values[np.isfinite(values)]
    if values.size < 10:
        return False
    low, high = np.percentile(values, [10.0, 90.0])
    return bool(high <= ONE_DEPTH_RATIO * low + 0.5)


#: a gap whose border seems one surface is still sky where most of its rows are runs of the sky's
#: colour at most this wide (pixels) between two depths (``_between_two_depths``).
GAP_SLOT_PX = 40


def _between_two_depths(
    labels: npt.NDArray[np.int32],
    c: int,
    box: npt.NDArray[np.int32],
    colour: Image,
    mine: npt.NDArray[np.float64],
    tolerance: float,
    disparity: npt.NDArray[np.float32],
    reach: int,
) -> bool:
    """Whether most rows of component ``c`` (box: x, y, w, h) lie in a slot (``_in_slot``, ``GAP_SLOT_PX``):
    a run of its colour, the unflat pixels beside it within ``reach`` included, whose two ends differ in depth.

    The ring test (``_one_depth_around``) takes percentiles over the whole border with a ratio
    loose enough for a facade seen askew, so a narrow gap between a gantry's post and a pole 3 m
    behind it (11.4 and 10.0 px at 20 m) passes for one surface; and the ring is mostly the gap's own
    unflat fringe, which holds what SGM carried in. Row by row the two ends still tell: synthetic
    `hanging` seed 17's sky between a barrier's post and a pole hung under the barrier, 2-37 voxels
    a frame over the lane (docs/results/voxel.md, "Session 70").
    """
    x, y, w, h = (int(v) for v in box[0:4])
    margin = reach + 1  # the pixels that bound a run lie inside the patch
    y0, x0 = max(y - margin, 0), max(x - margin, 0)
    own = labels[y0 : y + h + margin, x0 : x + w + margin] == c
    patch = colour[y0 : y + h + margin, x0 : x + w + margin].astype(np.float32)
    alike = np.all(np.abs(patch - mine.astype(np.float32)) <= tolerance, axis=2)
    near = cv2.dilate(own.view(np.uint8), np.ones((3, 3), np.uint8), iterations=reach).view(bool)
    slot = _in_slot(own | (near & alike), GAP_SLOT_PX, disparity[y0 : y + h + margin, x0 : x + w + margin])
    return bool(slot[own].mean() >= 0.5)


def _add_grown(
    sky: npt.NDArray[np.bool_],
    labels: npt.NDArray[np.int32],
    stats: npt.NDArray[np.int32],
    gaps: npt.NDArray[np.bool_],
    colour: Image,
    tolerance: float,
    reach: int,
) -> None:
    """Add to ``sky`` the gaps and the pixels of their colour up to ``reach`` pixels around them.

    Flatness is judged over a window, so the rows of sky next to a bar's edge are not flat and
    stay out of the gap; they hold the bar's disparity too and hang under it as a thin sheet.
    """
    boxes = stats[gaps]
    y0, x0 = max(int(boxes[:, cv2.CC_STAT_TOP].min()) - reach, 0), max(int(boxes[:, cv2.CC_STAT_LEFT].min()) - reach, 0)
    y1 = int((boxes[:, cv2.CC_STAT_TOP] + boxes[:, cv2.CC_STAT_HEIGHT]).max()) + reach
    x1 = int((boxes[:, cv2.CC_STAT_LEFT] + boxes[:, cv2.CC_STAT_WIDTH]).max()) + reach
    inner = gaps[labels[y0:y1, x0:x1]]
    near = cv2.dilate(inner.view(np.uint8), np.ones((3, 3), np.uint8), iterations=reach).view(bool)
    patch = colour[y0:y1, x0:x1]
    reference = np.array(cv2.mean(patch, mask=inner.view(np.uint8))[0:3], dtype=np.float32)
    alike = np.all(np.abs(patch.astype(np.int16) - reference) <= tolerance, axis=2)
    sky[y0:y1, x0:x1] |= inner | (near & alike)


def _gaps(
    labels: npt.NDArray[np.int32],
    stats: npt.NDArray[np.int32],
    is_sky: npt.NDArray[np.bool_],
    sky: npt.NDArray[np.bool_],
    colour: Image,
    tolerance: float,
    disparity: npt.NDArray[np.float32] | None = None,
    window: int = 0,
) -> npt.NDArray[np.bool_]:
    """Which flat components not joined to the top row have the open sky's colour, within its rows
    (``window`` rows lower at most, the flatness window's: the open sky ends where the flatness window first meets the
    horizon's edge or what stands on it, a row or two higher in one place than in another; hanging
    seed 9's 4,422-pixel gap under a sign ended one row lower than the open sky).

    With ``disparity``, one more test: the region's surroundings must disagree on its depth. A
    flat region takes its disparity from its border; under a bar that border is the bar above and
    the far horizon below, while a pale patch of a facade (KITTI: white walls under a white sky)
    is enclosed by the facade itself and keeps its points.

    Specks under ``MIN_GAP_PX`` are left alone: too small to carry a bar's disparity far.
    """
    count = len(stats)
    out = np.zeros(count, dtype=bool)
    sky_rows = np.flatnonzero(sky.any(axis=1))
    if not sky_rows.size:
        return out
    top = stats[:, cv2.CC_STAT_TOP]
    bottom = top + stats[:, cv2.CC_STAT_HEIGHT]  # one past the lowest row
    candidates = ~is_sky & (stats[:, cv2.CC_STAT_AREA] >= MIN_GAP_PX) & (bottom <= sky_rows.max() + 1 + window)
    candidates[0] = False  # label 0 is every pixel that is not flat
    if not candidates.any():
        return out
    sky_u8 = sky.view(np.uint8)
    for c in np.flatnonzero(candidates).tolist():
        x, y, w, h = (int(v) for v in stats[c, 0:4])
        own = (labels[y : y + h, x : x + w] == c).view(np.uint8)
        open_rows = sky_u8[y : y + h]
        if not open_rows.any():
            continue
        mine = np.array(cv2.mean(colour[y : y + h, x : x + w], mask=own)[0:3])
        theirs = np.array(cv2.mean(colour[y : y + h], mask=open_rows)[0:3])
        alike = bool(np.all(np.abs(mine - theirs) <= tolerance))
        out[c] = alike and (
            disparity is None
            or not _one_depth_around(labels, c, stats[c], disparity)
            or _between_two_depths(labels, c, stats[c], colour, mine, tolerance, disparity, window // 2 + 1)
        )
    return out
