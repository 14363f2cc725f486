"""Sub-pixel refinement of the matched disparity: a 1-D Lucas-Kanade step on the images themselves.

SGBM finds its sub-pixel part from a parabola through the aggregated Birchfield-Tomasi costs,
which are flat near their minimum. Its estimates are therefore pulled towards whole pixels
("pixel locking"): on synthetic `urban` the error is -0.15 px at a true fraction of 0.25 and
+0.14 px at 0.5, and its spread beyond 15 m is 0.13-0.16 px (median absolute deviation). At 20 m
on the synthetic rig a tenth of a pixel is 0.17 m, and the voxels are 0.25 m, so objects smear
across voxels along the line of sight (docs/results/stereo.md).

The refinement warps the right image by the current disparity and solves, in a Gaussian window,
for the common shift that best explains what is left over, a few times. It is the same
estimate the odometry makes for its features, done for every pixel at once with whole-image
OpenCV calls. Both images are high-passed first, so a difference of exposure between the
cameras is not read as a shift. Where the window holds more than one surface (its matched
disparities span more than ``span_px``) or the shift comes out larger than ``max_step_px``, the
matcher's value stays: a window across a depth edge would drag the nearer surface back. Nor is it
done above ``max_disparity_px``, where the matcher's error is a negligible share of the depth;
the work is then confined to the band of rows that holds something to refine, which leaves out
the near road at the bottom of the image (a quarter to a third of a 640x480 frame).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from services.stereo_depth.sgbm import DisparityMap, Image

#: per-iteration step cap (px): one wild window must not throw the next warp off its surface.
MAX_ITERATION_STEP_PX = 0.3
#: below this mean squared gradient (grey levels^2 per pixel) the window has no texture to go on.
MIN_GRADIENT_SQ = 1.0


@dataclass(frozen=True)
class SubpixelParams:
    """What the refinement needs from ``StereoConfig`` (``subpixel_*``)."""

    window: int = 11  # Gaussian window (px, odd); its sigma is window / 3.7
    iterations: int = 3
    span_px: float = 1.5  # the matched disparities in the window may span this much
    max_step_px: float = 0.75  # a larger total correction keeps the matcher's value
    highpass: int = 7  # box size of the local mean subtracted from both images
    max_disparity_px: float = 32.0  # nearer than this the matcher's value stays


def _highpassed(img: Image, size: int) -> np.ndarray:
    values = img.astype(np.float32)
    return values - cv2.blur(values, (size, size))


def _x_gradient(img: np.ndarray) -> np.ndarray:
    return cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)


@functools.lru_cache(maxsize=4)
def _pixel_grid(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Column and row of every pixel, as ``cv2.remap`` wants them; built once per image size."""
    cols = np.arange(w, dtype=np.float32)[None, :].repeat(h, 0)
    rows = np.arange(h, dtype=np.float32)[:, None].repeat(w, 1)
    cols.flags.writeable = rows.flags.writeable = False
    return cols, rows


def _window_span(disparity: DisparityMap, valid: np.ndarray, window: int) -> np.ndarray:
    """Largest minus smallest matched disparity in each pixel's window (invalid pixels ignored)."""
    kernel = np.ones((window, window), np.uint8)
    high = cv2.dilate(np.where(valid, disparity, -1e4).astype(np.float32), kernel)
    low = cv2.erode(np.where(valid, disparity, 1e4).astype(np.float32), kernel)
    return high - low


def refine_disparity(left: Image, right: Image, disparity: DisparityMap, params: SubpixelParams) -> DisparityMap:
    """``disparity`` with its sub-pixel part re-estimated from the images; NaN stays NaN."""
    valid = np.isfinite(disparity)
    refinable = valid & (_window_span(disparity, valid, params.window) <= params.span_px)
    refinable &= np.where(valid, disparity, np.inf) <= params.max_disparity_px
    rows_in_use = np.flatnonzero(refinable.any(axis=1))
    if len(rows_in_use) == 0:
        return disparity
    # how far a pixel's estimate reaches: each iteration's window takes in its neighbours' last
    # estimates, on top of the high-pass and the gradient. Cropped any closer, the band's edge shows.
    reach = params.iterations * (params.window // 2) + params.highpass // 2 + 2
    band = slice(max(0, int(rows_in_use[0]) - reach), min(disparity.shape[0], int(rows_in_use[-1]) + 1 + reach))
    cols, rows = _pixel_grid(*disparity.shape)
    height = band.stop - band.start
    grid = (cols[:height], rows[:height])  # the band's own rows start at 0
    refined = _refine_band(left[band], right[band], disparity[band], valid[band], grid, params)
    out = disparity.copy()
    take = refinable[band] & (np.abs(refined - np.where(valid[band], disparity[band], 0.0)) <= params.max_step_px)
    out[band] = np.where(take, refined, disparity[band])
    return out


def _refine_band(
    left: Image,
    right: Image,
    disparity: DisparityMap,
    valid: np.ndarray,
    grid: tuple[np.ndarray, np.ndarray],
    params: SubpixelParams,
) -> np.ndarray:
    """Lucas-Kanade estimates for every pixel of a band of rows (where invalid: meaningless)."""
    left_hp = _highpassed(left, params.highpass)
    right_hp = _highpassed(right, params.highpass)
    grad_l = _x_gradient(left_hp)
    weight = valid.astype(np.float32)
    sigma = params.window / 3.7
    ksize = (params.window, params.window)
    cols, rows = grid
    current = np.where(valid, disparity, 0.0).astype(np.float32)
    # the left image's gradient stands for the warped right one's (inverse compositional): the
    # normal equations' left side is then fixed and each iteration needs one warp, not two. On
    # synthetic `urban` seed 7 the spread per range moved by at most 0.002 px against the mean of
    # both gradients, and the refinement took 11 ms instead of 19 (docs/results/stereo.md)
    den = cv2.GaussianBlur(grad_l * grad_l * weight, ksize, sigma)
    textured = den > MIN_GRADIENT_SQ
    inv_den = np.where(textured, -1.0 / np.maximum(den, 1e-6), 0.0).astype(np.float32)
    grad_w = grad_l * weight
    for _ in range(params.iterations):
        warped = cv2.remap(right_hp, cols - current, rows, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
        # left(x) = right(x - d - s) ~ warped - s * grad, so s = -sum(grad * residual) / sum(grad^2)
        num = cv2.GaussianBlur(grad_w * (left_hp - warped), ksize, sigma)
        current += np.clip(num * inv_den, -MAX_ITERATION_STEP_PX, MAX_ITERATION_STEP_PX)
    return current
