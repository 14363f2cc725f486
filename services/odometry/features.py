"""Corner features with Sobel-patch descriptors, in the manner of libviso2 (StereoScan).

FAST corners give repeatable, cheap keypoints; a per-cell cap keeps them spread over the image so
that no textured patch (a hedge, a fence) can monopolise the motion estimate. The descriptor is
libviso2's idea: horizontal and vertical Sobel responses sampled on a sparse grid around the
corner, compared with the sum of absolute differences. Unlike ORB it is not rotation-invariant,
which a vehicle camera does not need, and it rejects illumination offsets because gradients do.
"""

from __future__ import annotations

import typing
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

#: descriptor sample offsets (dx, dy): a 5x5 grid of step 2 over an 9x9 window.
_GRID = np.array([(dx, dy) for dy in (-4, -2, 0, 2, 4) for dx in (-4, -2, 0, 2, 4)], dtype=np.int32)
#: how far a feature must stay from the border so that its descriptor window fits.
BORDER = 6


@dataclass(frozen=True)
class Features:
    """Keypoints of one image: positions (x, y) in pixels, corner strength and descriptors."""

    xy: npt.NDArray[np.float32]  # N x 2
    response: npt.NDArray[np.float32]  # N
    descriptors: npt.NDArray[np.uint8]  # N x D, Sobel samples offset by 128

    def __len__(self) -> int:
        return int(self.xy.shape[0])

    def subset(self, index: npt.NDArray[np.intp]) -> Features:
        return Features(xy=self.xy[index], response=self.response[index], descriptors=self.descriptors[index])


def to_gray(rgb: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    """Luminance of an RGB image (a grey image is passed through)."""
    if rgb.ndim == 2:
        return rgb
    return cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)


class FeatureDetector:
    """Finds FAST corners, keeps the strongest few per grid cell and describes them.

    A dark or low-contrast pair (dusk, fog) has few corners above a fixed threshold, so the
    threshold halves, down to ``min_threshold``, until the left image has ``min_corners``; the
    right image uses the same threshold, so both see the same corners.
    """

    def __init__(
        self,
        threshold: int,
        cell_px: int,
        per_cell: int,
        max_features: int,
        min_corners: int = 0,
        min_threshold: int = 4,
    ) -> None:
        levels = [threshold]
        while levels[-1] // 2 >= min_threshold:
            levels.append(levels[-1] // 2)
        self.fast = [cv2.FastFeatureDetector_create(threshold=t, nonmaxSuppression=True) for t in levels]
        self.cell_px = cell_px
        self.per_cell = per_cell
        self.max_features = max_features
        self.min_corners = min_corners

    def detect(self, gray: npt.NDArray[np.uint8], level: int = 0) -> Features:
        """Corners spread over the image, each with its descriptor."""
        return self._describe(gray, self.fast[level].detect(gray, None))

    def detect_pair(self, left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8]) -> tuple[Features, Features]:
        """Corners of a stereo pair at the highest threshold that finds enough in the left image."""
        level, keypoints = 0, self.fast[0].detect(left, None)
        while len(keypoints) < self.min_corners and level + 1 < len(self.fast):
            level += 1
            keypoints = self.fast[level].detect(left, None)
        return self._describe(left, keypoints), self.detect(right, level)

    def _describe(self, gray: npt.NDArray[np.uint8], keypoints: typing.Sequence[cv2.KeyPoint]) -> Features:
        h, w = gray.shape
        if not keypoints:
            return _empty()
        xy = cv2.KeyPoint_convert(keypoints).astype(np.float32).reshape(-1, 2)
        response = np.fromiter((k.response for k in keypoints), dtype=np.float32, count=len(keypoints))
        inside = (xy[:, 0] >= BORDER) & (xy[:, 0] < w - BORDER) & (xy[:, 1] >= BORDER) & (xy[:, 1] < h - BORDER)
        xy, response = xy[inside], response[inside]
        keep = strongest_per_cell(xy, response, self.cell_px, self.per_cell, self.max_features)
        xy, response = xy[keep], response[keep]
        return Features(xy=xy, response=response, descriptors=describe(gray, xy))


def strongest_per_cell(
    xy: npt.NDArray[np.float32], score: npt.NDArray[np.float32], cell_px: int, per_cell: int, limit: int
) -> npt.NDArray[np.intp]:
    """Indices of the ``per_cell`` highest scores in each grid cell, at most ``limit`` overall."""
    if len(xy) == 0:
        return np.zeros(0, dtype=np.intp)
    cells = (xy // cell_px).astype(np.int64)
    key = cells[:, 1] * 100_000 + cells[:, 0]
    order = np.lexsort((-score, key))
    sorted_key = key[order]
    first = np.r_[True, sorted_key[1:] != sorted_key[:-1]]
    starts = np.maximum.accumulate(np.where(first, np.arange(len(order)), 0))
    rank = np.arange(len(order)) - starts
    chosen = order[rank < per_cell]
    if len(chosen) > limit:
        chosen = chosen[np.argsort(-score[chosen], kind="stable")[:limit]]
    return np.sort(chosen)


def describe(gray: npt.NDArray[np.uint8], xy: npt.NDArray[np.float32]) -> npt.NDArray[np.uint8]:
    """Sobel du and dv sampled on the descriptor grid around each (integer-rounded) keypoint."""
    du = cv2.Sobel(gray, cv2.CV_16S, 1, 0, ksize=3)
    dv = cv2.Sobel(gray, cv2.CV_16S, 0, 1, ksize=3)
    ij = np.rint(xy).astype(np.int32)
    cols = ij[:, 0:1] + _GRID[None, :, 0]
    rows = ij[:, 1:2] + _GRID[None, :, 1]
    desc = np.concatenate([du[rows, cols], dv[rows, cols]], axis=1)
    return (np.clip(desc // 4, -128, 127) + 128).astype(np.uint8)


def _empty() -> Features:
    return Features(
        xy=np.zeros((0, 2), np.float32),
        response=np.zeros(0, np.float32),
        descriptors=np.zeros((0, 2 * len(_GRID)), np.uint8),
    )
