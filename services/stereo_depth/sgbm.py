"""One OpenCV semi-global matching pass, for the left or the right view, over the whole image.

OpenCV's StereoSGBM leaves the first ``numDisparities`` columns without output (6-9 % of KITTI's
truth pixels): padding both images on the left by the search range lets those columns be matched
against whatever of them the other camera saw. The right-view disparity comes from the same
matcher on mirrored images with the views swapped, since OpenCV only matches left to right.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from common.errors import ConfigError

Image = npt.NDArray[np.uint8]
DisparityMap = npt.NDArray[np.float32]

MODES: dict[str, int] = {
    "3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    "sgbm": cv2.STEREO_SGBM_MODE_SGBM,
    "hh": cv2.STEREO_SGBM_MODE_HH,
    "hh4": cv2.STEREO_SGBM_MODE_HH4,
}


def round_up_16(value: float) -> int:
    """StereoSGBM wants the number of disparities as a positive multiple of 16."""
    return max(16, int(np.ceil(value / 16.0)) * 16)


@dataclass(frozen=True)
class SgbmParams:
    """What one pass needs; P1/P2 are already scaled by channels and block area."""

    num_disparities: int
    block_size: int
    p1: int
    p2: int
    uniqueness: int
    speckle_window: int
    speckle_range: int
    pre_filter_cap: int
    mode: str
    pad_left: bool


class SgbmPass:
    """A configured StereoSGBM returning float disparities in pixels, NaN where it gave none."""

    def __init__(self, params: SgbmParams) -> None:
        if params.mode not in MODES:
            raise ConfigError(f"stereo.mode {params.mode!r} unknown; allowed: {sorted(MODES)}")
        if params.num_disparities <= 0 or params.num_disparities % 16:
            raise ConfigError(f"number of disparities {params.num_disparities} is not a positive multiple of 16")
        if params.block_size < 1 or params.block_size % 2 == 0:
            raise ConfigError(f"stereo.block_size {params.block_size} must be odd and positive")
        self.params = params
        self._sgbm = cv2.StereoSGBM_create(
            minDisparity=0,
            numDisparities=params.num_disparities,
            blockSize=params.block_size,
            P1=params.p1,
            P2=params.p2,
            disp12MaxDiff=-1,  # ignored by the 3-way mode anyway; consistency.py does the check
            preFilterCap=params.pre_filter_cap,
            uniquenessRatio=params.uniqueness,
            speckleWindowSize=params.speckle_window,
            speckleRange=params.speckle_range,
            mode=MODES[params.mode],
        )

    def scale_penalties(self, factor: float) -> None:
        """P1 and P2 at ``factor`` times their configured values, until the next call (exposure.py)."""
        self._sgbm.setP1(max(1, round(self.params.p1 * factor)))
        self._sgbm.setP2(max(2, round(self.params.p2 * factor)))

    def left(self, left: Image, right: Image) -> DisparityMap:
        """Disparity of each left pixel (its match sits ``d`` columns to the left in the right image)."""
        pad = self.params.num_disparities if self.params.pad_left else 0
        if pad:
            left = cv2.copyMakeBorder(left, 0, 0, pad, 0, cv2.BORDER_REPLICATE)
            right = cv2.copyMakeBorder(right, 0, 0, pad, 0, cv2.BORDER_REPLICATE)
        fixed = self._sgbm.compute(left, right)[:, pad:]
        disparity = fixed.astype(np.float32) * np.float32(1.0 / 16.0)  # 4 fractional bits
        disparity[fixed < 0] = np.nan  # OpenCV marks "no match" as (minDisparity - 1) * 16
        return disparity

    def right(self, left: Image, right: Image) -> DisparityMap:
        """Disparity of each right pixel (its match sits ``d`` columns to the right in the left image)."""
        mirrored = self.left(np.ascontiguousarray(right[:, ::-1]), np.ascontiguousarray(left[:, ::-1]))
        return np.ascontiguousarray(mirrored[:, ::-1])
