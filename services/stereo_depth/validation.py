"""Refuse a stereo frame that cannot be matched, naming what is wrong, before any work is done."""

from __future__ import annotations

import math

import cv2
import numpy as np

from common.errors import CalibrationError, InputError
from common.messages import Calibration, StereoFrame

#: the smallest image the two-level matcher can work on (the half-resolution pass needs rows).
MIN_SIDE_PX: int = 8
#: grey-level spread below which an image holds nothing to match (sensor noise is 1-2 levels).
MIN_GREY_STD: float = 2.5


def check_images(left: np.ndarray, right: np.ndarray) -> None:
    """Two uint8 RGB images of one size."""
    for name, img in (("left", left), ("right", right)):
        if not isinstance(img, np.ndarray):
            raise InputError(f"{name} image is a {type(img).__name__}, not a numpy array")
        if img.ndim != 3 or img.shape[2] != 3:
            raise InputError(f"{name} image has shape {img.shape}; an H x W x 3 RGB image is required")
        if img.dtype != np.uint8:
            raise InputError(f"{name} image has dtype {img.dtype}; uint8 is required")
        if min(img.shape[:2]) < MIN_SIDE_PX:
            raise InputError(f"{name} image is {img.shape[1]}x{img.shape[0]}; at least {MIN_SIDE_PX} px a side")
    if left.shape != right.shape:
        (lh, lw), (rh, rw) = left.shape[:2], right.shape[:2]
        raise InputError(f"left image is {lw}x{lh} but right is {rw}x{rh}; a rectified pair has one size")


def check_calibration(calib: Calibration, width: int, height: int) -> None:
    """Positive finite focal lengths and baseline, a finite centre and pose, the image's own size."""
    for name in ("fx", "fy", "baseline"):
        value = float(getattr(calib, name))
        if not math.isfinite(value) or value <= 0.0:
            raise CalibrationError(f"calibration {name} is {value}; a finite value > 0 is required")
    for name in ("cx", "cy"):
        value = float(getattr(calib, name))
        if not math.isfinite(value):
            raise CalibrationError(f"calibration {name} is {value}; a finite value is required")
    if (calib.width, calib.height) != (width, height):
        raise CalibrationError(
            f"calibration is for {calib.width}x{calib.height} images but the frame's are {width}x{height}"
        )
    pose = np.asarray(calib.cam_to_vehicle)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise CalibrationError(f"cam_to_vehicle must be a finite 4x4 matrix, got shape {pose.shape}")


def check_frame(frame: StereoFrame) -> None:
    check_images(frame.left, frame.right)
    check_calibration(frame.calib, frame.left.shape[1], frame.left.shape[0])


def is_textureless(image: np.ndarray, min_std: float = MIN_GREY_STD) -> bool:
    """True for a blank image (all black, all white, one grey) or one holding only sensor noise.

    SGM still "matches" independent noise: on black frames with 1-2 grey levels of noise, 2-4 %
    of the pixels passed every check, i.e. thousands of phantom points. A real scene's grey
    levels spread over tens of levels even at dusk.
    """
    grey = cv2.cvtColor(np.ascontiguousarray(image[::2, ::2]), cv2.COLOR_RGB2GRAY)
    _, std = cv2.meanStdDev(grey)
    return float(std[0, 0]) < min_std
