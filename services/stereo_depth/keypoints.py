"""Corners followed from frame to frame in the left image, each with its own stereo disparity.

Along the line of sight a cluster's range says little about its speed: what is in it changes from
frame to frame (a neighbour merged in, a fringe of smear, a bin passed by), and a walker at 20 m
moves 0.15-0.2 m a frame where those changes move the cluster by metres. A corner on the walker
stays on the walker. Followed over eight frames and triangulated in each, corners picked inside
the truth boxes of synthetic urban's walkers gave a speed over 1.0 m/s in 85-94 % of walker-frames,
on its poles, bins and parked cars in 0-12 % (docs/results/tracking.md, "Session 40"). That is
Franke's 6D-Vision measurement, sparse: the tracker fits each corner's line (keypoint_motion.py).

Corners are Shi-Tomasi's, topped up each frame where none is followed yet; each is followed by
pyramidal Lucas-Kanade and kept only if following it back lands where it started. Its disparity
is a Lucas-Kanade match of its own into the right image, started from the matcher's disparity and
held to the same row: the dense refinement (subpixel.py) leaves the matcher's value beyond 32 px
and wherever its window spans a depth edge, which is where corners are.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from services.stereo_depth.sgbm import DisparityMap, Image

NDArray = npt.NDArray[Any]

#: pyramid levels of the temporal match: 3 covers 20 px of image motion a frame (0.1 s) and more.
PYRAMID_LEVELS: int = 3
#: the stereo match starts from the matcher's disparity, within a pixel or two: no pyramid.
STEREO_LEVELS: int = 0
#: side of the window Shi-Tomasi's measure sums the gradients over.
CORNER_BLOCK_PX: int = 5
LK_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03)


@dataclass(frozen=True)
class KeypointParams:
    """What the keypoint tracker needs from ``StereoConfig`` (``keypoint_*``)."""

    max_count: int = 8000  # corners followed at once; 0 = off
    cell_px: int = 4  # at most one new corner per square cell of this size
    quality: float = 0.001  # weakest corner taken, as a share of the frame's strongest (Shi-Tomasi's measure)
    window_px: int = 9  # Lucas-Kanade window (px, odd): 11 cost twice the time for as many walker corners
    max_return_px: float = 0.6  # a corner followed back must land this near where it started
    max_row_px: float = 0.5  # its right-image match this near its row (rectified images)
    max_disparity_step_px: float = 1.0  # and its disparity this near the matcher's


@dataclass(frozen=True)
class Keypoints:
    """This frame's followed corners that have a disparity: ids, pixel (u, v) and disparity (px)."""

    ids: npt.NDArray[np.int64]
    uv: npt.NDArray[np.float32]
    disparity: npt.NDArray[np.float32]


class KeypointTracker:
    """Left-image corners with ids that persist while each corner can be followed."""

    def __init__(self, params: KeypointParams) -> None:
        self.params = params
        self._grey: Image | None = None
        self._frame_id = -1
        self._ids = np.zeros(0, dtype=np.int64)
        self._uv = np.zeros((0, 2), dtype=np.float32)
        self._next_id = 0

    def update(
        self, left: Image, right: Image, disparity: DisparityMap, frame_id: int, min_disparity: float = 0.0
    ) -> Keypoints:
        """Follow last frame's corners into ``left`` (grey), top them up, and match them into ``right``.

        A frame that is not newer than the last one, or of another size, starts again: its corners
        could not have come from the last frame's.
        """
        if self._grey is None or self._grey.shape != left.shape or frame_id <= self._frame_id:
            self._ids, self._uv = self._ids[:0], self._uv[:0]
        elif len(self._ids):
            uv, ok = self._follow(self._grey, left, self._uv, self._uv, PYRAMID_LEVELS)
            self._ids, self._uv = self._ids[ok], uv[ok]
        self._top_up(left, disparity, min_disparity)
        self._grey, self._frame_id = left, frame_id
        return self._stereo(left, right, disparity)

    def _follow(
        self, a: Image, b: Image, uv: NDArray, guess: NDArray, levels: int
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.bool_]]:
        """Lucas-Kanade from ``a`` to ``b`` and back; where each point went and whether it came back."""
        size = (self.params.window_px, self.params.window_px)
        start = np.array(uv, dtype=np.float32).reshape(-1, 1, 2)
        there, found, _ = cv2.calcOpticalFlowPyrLK(
            a, b, start, np.array(guess, dtype=np.float32).reshape(-1, 1, 2),  # copies: OpenCV writes into it
            winSize=size, maxLevel=levels, criteria=LK_CRITERIA, flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
        )  # fmt: skip
        back, returned, _ = cv2.calcOpticalFlowPyrLK(
            b, a, there, start.copy(), winSize=size, maxLevel=levels, criteria=LK_CRITERIA,
            flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
        )  # fmt: skip
        err = np.linalg.norm((back - start).reshape(-1, 2), axis=1)
        ok = (found.ravel() == 1) & (returned.ravel() == 1) & (err <= self.params.max_return_px)
        there = there.reshape(-1, 2)
        h, w = a.shape[:2]
        ok &= (there[:, 0] >= 0) & (there[:, 0] <= w - 1) & (there[:, 1] >= 0) & (there[:, 1] <= h - 1)
        return there, ok

    def _top_up(self, grey: Image, disparity: DisparityMap, min_disparity: float) -> None:
        """A new corner in each grid cell that has none yet, where the disparity is ``min_disparity`` or more.

        One per cell, the cell's strongest, rather than the frame's strongest corners: those lie on
        facades and the road's texture, and a walker's weaker corners would never be followed.
        """
        p = self.params
        room = p.max_count - len(self._ids)
        if room <= 0:
            return
        eigen = cv2.cornerMinEigenVal(grey, CORNER_BLOCK_PX)
        peak = (eigen >= cv2.dilate(eigen, None)) & (eigen > p.quality * float(eigen.max()))
        with np.errstate(invalid="ignore"):
            peak &= disparity >= min_disparity  # NaN: no
        rows, cols = np.nonzero(peak)
        cell = p.cell_px
        width = grey.shape[1] // cell + 1
        key = (rows // cell) * width + cols // cell
        held = np.round(self._uv).astype(np.int64)
        free = ~np.isin(key, (held[:, 1] // cell) * width + held[:, 0] // cell)
        rows, cols, key, score = rows[free], cols[free], key[free], eigen[rows[free], cols[free]]
        order = np.lexsort((-score, key))
        first = order[np.r_[True, key[order][1:] != key[order][:-1]]] if len(order) else order
        if len(first) > room:
            first = first[np.argsort(-score[first], kind="stable")[:room]]
        new = np.stack([cols[first], rows[first]], axis=1).astype(np.float32)
        self._ids = np.concatenate([self._ids, np.arange(self._next_id, self._next_id + len(new), dtype=np.int64)])
        self._uv = np.concatenate([self._uv, new])
        self._next_id += len(new)

    def _stereo(self, left: Image, right: Image, disparity: DisparityMap) -> Keypoints:
        """Each corner's disparity, matched into the right image from the matcher's value."""
        p = self.params
        if len(self._ids) == 0:
            return Keypoints(self._ids.copy(), self._uv.copy(), np.zeros(0, dtype=np.float32))
        h, w = disparity.shape
        col = np.clip(np.round(self._uv[:, 0]).astype(np.intp), 0, w - 1)
        row = np.clip(np.round(self._uv[:, 1]).astype(np.intp), 0, h - 1)
        seed = disparity[row, col]
        known = np.isfinite(seed)
        guess = self._uv - np.stack([np.where(known, seed, 0.0), np.zeros(len(seed))], axis=1).astype(np.float32)
        there, ok = self._follow(left, right, self._uv, guess, STEREO_LEVELS)
        d = self._uv[:, 0] - there[:, 0]
        with np.errstate(invalid="ignore"):
            ok &= known & (np.abs(there[:, 1] - self._uv[:, 1]) <= p.max_row_px)
            ok &= (np.abs(d - seed) <= p.max_disparity_step_px) & (d > 0)
        return Keypoints(self._ids[ok].copy(), self._uv[ok].copy(), d[ok].astype(np.float32))
