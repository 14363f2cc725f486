"""Left-right consistency: a left pixel keeps its disparity only if the right view agrees.

Occluded pixels (seen by the left camera only) and mismatches in repetitive or blank texture
fail this test; leaving them out is what keeps the points honest (the truth says "unknown",
not "guess the background").
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from services.stereo_depth.sgbm import DisparityMap


def left_right_check(left_disp: DisparityMap, right_disp: DisparityMap, max_diff: float) -> DisparityMap:
    """NaN where the right view's disparity at ``x - d`` differs by more than ``max_diff`` (a new array)."""
    height, width = left_disp.shape
    map_x = np.arange(width, dtype=np.float32)[None, :] - np.nan_to_num(left_disp, nan=-1.0e6)
    map_y = np.broadcast_to(np.arange(height, dtype=np.float32)[:, None], (height, width))
    seen = cv2.remap(
        right_disp,
        map_x,
        np.ascontiguousarray(map_y),
        cv2.INTER_NEAREST,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=float("nan"),
    )  # off the image (and invalid pixels, sent far away) read NaN, which never agrees
    agree = np.abs(seen - left_disp) <= max_diff
    return np.where(agree, left_disp, np.float32(np.nan)).astype(np.float32, copy=False)


def upsample(disp: DisparityMap, shape: tuple[int, int], factor: float) -> DisparityMap:
    """A coarse disparity at full resolution: nearest neighbour (no blending across edges or NaN)."""
    full = cv2.resize(disp, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)
    return (full * np.float32(factor)).astype(np.float32, copy=False)


def within_neighbours(
    candidate: DisparityMap, reference: DisparityMap, window: int, max_diff: float
) -> npt.NDArray[np.bool_]:
    """Where ``candidate`` lies within the range of ``reference``'s valid values around it (± max_diff).

    A hole filled from the coarse pass must be corroborated by the fine pass around it: in an
    occlusion the coarse value bleeds from the foreground and leaves that range, and a hole with
    no fine value within reach stays a hole.
    """
    far = np.float32(-1.0e6)
    kernel = np.ones((window, window), np.uint8)
    valid = np.isfinite(reference)
    high = cv2.dilate(np.where(valid, reference, far).astype(np.float32), kernel)
    low = -cv2.dilate(np.where(valid, -reference, far).astype(np.float32), kernel)
    return (high > far / 2) & (candidate <= high + max_diff) & (candidate >= low - max_diff)


def textured(image: npt.NDArray[np.uint8], window: int, min_gradient: float) -> npt.NDArray[np.bool_]:
    """Where the mean horizontal grey gradient over a ``window`` square reaches ``min_gradient``.

    Matching cost is built on that gradient: where it is flat (sky, haze, blank walls), SGM's
    smoothness carries values in from the edges and the two views can agree on the same wrong
    value, which a left-right check does not catch.
    """
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    gradient = np.abs(cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3))
    return cv2.blur(gradient, (window, window)) >= np.float32(min_gradient)
