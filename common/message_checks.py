"""What a decoded message must satisfy beyond its types: finite numbers and fields that agree.

A message can be well-typed and still poison a stage: one NaN in a pose spreads through every
later frame of the odometry's state, a zero baseline divides, images that do not fit their
calibration reproject to nonsense. The decoder (``common.codec.decode``) runs these checks, so
such a message is refused once, counted and dropped, and no stage sees it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from common.errors import DecodeError

NDArray = npt.NDArray[Any]

#: float arrays where a non-finite value means something: NaN disparity is "no match", an infinite
#: covariance "unknown". Everywhere else NaN or inf is refused: one NaN in a pose or a point spreads
#: through every later frame of a stage's state.
NAN_FIELDS: frozenset[str] = frozenset({"disparity"})
INF_FIELDS: frozenset[str] = frozenset({"covariance", "position_cov", "velocity_cov"})


def check_finite(arr: NDArray, name: str, where: str) -> None:
    """Refuse NaN and inf in a decoded float array, except where they carry a meaning."""
    if arr.dtype.kind != "f" or name in NAN_FIELDS:
        return
    bad = np.isnan(arr) if name in INF_FIELDS else ~np.isfinite(arr)
    if bad.any():
        raise DecodeError(f"{where}: {int(bad.sum())} non-finite value(s)")


def check_consistent(msg: Any, where: str) -> None:
    """Facts between fields that every stage relies on: sizes that agree, a calibration one can divide by."""
    if msg.frame_id < 0 or msg.stamp_ns < 0:
        raise DecodeError(f"{where}: negative frame_id {msg.frame_id} or stamp_ns {msg.stamp_ns}")
    calib = getattr(msg, "calib", None)
    if calib is not None and (
        min(calib.fx, calib.fy, calib.baseline) <= 0 or min(calib.width, calib.height) <= 0
    ):
        raise DecodeError(f"{where}.calib: focal lengths, baseline and image size must be positive")
    if calib is not None and hasattr(msg, "left"):  # a StereoFrame
        size = (msg.calib.height, msg.calib.width)
        if msg.left.shape[:2] != size or msg.right.shape[:2] != size:
            raise DecodeError(f"{where}: images of {msg.left.shape[:2]} and {msg.right.shape[:2]}, calibration {size}")
    if hasattr(msg, "points") and hasattr(msg, "colors") and len(msg.points) != len(msg.colors):
        raise DecodeError(f"{where}: {len(msg.points)} points but {len(msg.colors)} colours")
    if hasattr(msg, "keypoint_ids") and not len(msg.keypoint_ids) == len(msg.keypoints) == len(msg.keypoint_std):
        counts = (len(msg.keypoint_ids), len(msg.keypoints), len(msg.keypoint_std))
        raise DecodeError(f"{where}: {counts[0]} keypoint ids, {counts[1]} keypoints, {counts[2]} range doubts")
