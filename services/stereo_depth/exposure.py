"""A dim pair matched with SGM's smoothness penalties scaled down to its contrast.

SGM weighs a pixel's matching cost, built from grey-level differences, against two smoothness
penalties, P1 and P2, in the same units, and those were measured on daylight images. At dusk the
scene spans a third of the grey levels (the synthetic `lowtexture` street 60 between its 1st and
99th percentiles, daylight `urban` 183, KITTI 250), so every cost shrinks threefold against
fixed penalties and smoothness wins where the data should: a post or a far cyclist a few pixels
wide takes the wall's disparity behind it, and the disparity beside depth steps ramps further.
The pair's gain is what would bring its span up to ``span`` levels (at most ``MAX_GAIN``); SGM
matches the camera's own images with both penalties divided by it, so the balance is daylight's.

Pairs already spanning ``span`` levels have gain 1 and are matched bit for bit as before: every
daylight recording measured here (synthetic, KITTI and Middlebury, 168-255 levels) is.
Stretching the images instead, or also reading the matcher's grey-level tests (texture, hidden
fill, sky) on a stretched view, was measured and left out (docs/results/stereo.md, "Session 39").
"""

from __future__ import annotations

import numpy as np

from services.stereo_depth.sgbm import Image

#: percentiles whose distance is the image's contrast: the darkest and brightest 1 % are outliers
#: (specular highlights, a street lamp, the black of a tunnel mouth).
LOW_PCT, HIGH_PCT = 1.0, 99.0
#: the largest gain: beyond it sensor noise, not the scene, would set the costs.
MAX_GAIN = 4.0


def contrast_gain(image: Image, span: float) -> float:
    """How far short of ``span`` grey levels ``image`` (uint8, grey or colour) falls, as a factor >= 1."""
    if span <= 0.0:
        return 1.0
    cumulative = np.cumsum(np.bincount(image.ravel(), minlength=256)) / max(image.size, 1)
    lo, hi = np.searchsorted(cumulative, (LOW_PCT / 100.0, HIGH_PCT / 100.0))
    width = max(float(hi - lo), 1.0)
    return 1.0 if width >= span else min(span / width, MAX_GAIN)
