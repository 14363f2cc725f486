"""A dim pair matched as if in daylight: its contrast measured, the matcher's grey-level settings scaled to it.

Every setting of the matcher that counts grey levels was measured on daylight images: SGM's
smoothness penalties P1 and P2 (against a matching cost built from grey-level differences), the
texture test's gradient, the hidden fill's colour step that must not be crossed. At dusk the
scene spans a third of the grey levels (the synthetic `lowtexture` street 60 between its 1st and
99th percentiles, daylight `urban` 183, KITTI 250), so every difference shrinks threefold
against fixed settings. SGM then carries a near surface's disparity across the background beside
it, and the hidden fill runs across the edge that should stop it: the smear that joins a walker
to the wall behind him.

The pair's gain is what brings its span up to ``span`` levels (at most ``MAX_GAIN``). SGM matches
the camera's own images with its penalties divided by the gain, so their costs keep their
resolution and no gradient is clipped at ``pre_filter_cap`` that was not before; the tests that
count grey levels read the left image stretched by the gain. Pairs already spanning ``span``
levels have gain 1 and are matched bit for bit as before: every daylight recording measured
here (synthetic, KITTI and Middlebury, 168-255 levels) is. docs/results/stereo.md, "Session 39",
has the measurements, and the variants left out.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

Image = npt.NDArray[Any]

#: percentiles whose distance is the image's contrast: the darkest and brightest 1 % are outliers
#: (specular highlights, the black of a tunnel mouth) that a stretch may clip.
LOW_PCT, HIGH_PCT = 1.0, 99.0
#: the most a pair is amplified: beyond it the sensor noise, not the scene, fills the range.
MAX_GAIN = 4.0


def _levels(image: Image) -> tuple[float, float]:
    """The grey levels at ``LOW_PCT`` and ``HIGH_PCT`` of ``image`` (uint8), from its histogram."""
    counts = np.bincount(image.ravel(), minlength=256)
    cumulative = np.cumsum(counts) / max(int(counts.sum()), 1)
    return float(np.searchsorted(cumulative, LOW_PCT / 100.0)), float(np.searchsorted(cumulative, HIGH_PCT / 100.0))


def contrast_gain(image: Image, span: float) -> float:
    """How much ``image`` (uint8, grey or colour) must be stretched to span ``span`` levels; 1 if it does."""
    if span <= 0.0:
        return 1.0
    lo, hi = _levels(image)
    width = max(hi - lo, 1.0)
    return 1.0 if width >= span else min(span / width, MAX_GAIN)


def stretched(image: Image, gain: float) -> Image:
    """``image`` stretched by ``gain`` about its middle grey level (the same image if ``gain`` is 1)."""
    if gain == 1.0:
        return image
    lo, hi = _levels(image)
    half = 0.5 * gain * (hi - lo)
    centre = float(np.clip(0.5 * (lo + hi), half, 255.0 - half))  # the stretched range inside 0..255 if it fits
    levels = np.arange(256, dtype=np.float64)
    lut = np.clip(np.rint((levels - 0.5 * (lo + hi)) * gain + centre), 0, 255).astype(np.uint8)
    return cv2.LUT(image, lut)
