"""Pixels on the ramp a matcher leaves across a depth step: optionally dropped from the point cloud.

Where a thin or near object stands in front of a farther one, SGM and the sub-pixel refinement
give the pixels between them disparities in between: a pole at 20 m (12.3 px) before a kiosk at
23 m (10.4 px) had four columns at 10.6-11.8 px on synthetic urban-s3. Each such pixel is a point
in the empty space between the two surfaces, and a column of them strings voxels along the line
of sight from one object to the other, so the colour flood fill joins a walker to the wall behind
it and a pole to a kiosk.

A pixel is on such a ramp when the mean disparity of ``width`` pixels ``reach`` columns to its
left and the same to its right differ by more than ``step_px``, its own disparity lies strictly
between them, more than ``margin_px`` from either, and each of those two plateaus is flat: it
changes end to end by at most ``flat_share`` of the step. Both surfaces' own pixels, even at the
step, are within the margin of one side and stay. The flatness test keeps surfaces seen at a
slant: a wall or a parked car's side 3 m beside the lens changes by 0.13 px per column for a
0.4 m baseline, a step of more than 1 px over the ten columns between the plateaus, and without
the test it vanished from the cloud. Only rows are tested: the same test down the columns as
well cost 3.5 points of objects in one cluster on the tuning runs.

Off by default (``stereo.ramp_step_px = 0``). With it on, synthetic scenes had fewer merged
clusters and phantom obstacles, but KITTI tracking 0001 had more false moving tracks, mostly on
trees and hedges (docs/results/voxel.md, "Session 16"). The published disparity image stays the
matcher's own either way, as with the rig's bias correction: only the cloud leaves these pixels
out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.errors import ConfigError

F32 = npt.NDArray[np.float32]


@dataclass(frozen=True)
class RampFilter:
    """The ramp test's settings (``stereo.ramp_*``); one instance serves every frame of any size."""

    step_px: float = 1.0
    reach: int = 4
    width: int = 3
    margin_px: float = 0.2
    flat_share: float = 0.15

    def __post_init__(self) -> None:
        if self.reach < 1 or self.width < 1 or self.step_px <= 0.0 or self.margin_px < 0.0 or self.flat_share < 0.0:
            raise ConfigError(
                "stereo.ramp_reach_px and ramp_width_px must be >= 1, ramp_step_px > 0, and ramp_margin_px and "
                f"ramp_flat_share >= 0; got {self}"
            )

    def mask(self, disparity: F32) -> npt.NDArray[np.bool_]:
        """True for pixels strictly between the two plateaus of a depth step (see the module text)."""
        d = np.asarray(disparity, dtype=np.float32)
        rows, cols = d.shape
        k, w = self.reach, self.width
        out = np.zeros(d.shape, dtype=bool)
        span = k + w - 1  # the farthest column either plateau reaches
        if cols <= 2 * span:
            return out
        finite = np.isfinite(d)
        values = np.where(finite, d, np.float32(0.0))
        # sums over every run of w columns: run[:, j] covers columns j .. j + w - 1
        run = np.zeros((rows, cols - w + 1), dtype=np.float32)
        count = np.zeros((rows, cols - w + 1), dtype=np.float32)
        for o in range(w):
            run += values[:, o : cols - w + 1 + o]
            count += finite[:, o : cols - w + 1 + o]
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = run / count  # NaN where a run holds no disparity
        # pixel u (span <= u < cols - span): left plateau = run starting at u - span, right = at u + k
        left = mean[:, 0 : cols - 2 * span]
        right = mean[:, span + k : cols - w + 1]
        centre = d[:, span : cols - span]
        low, high = np.fmin(left, right), np.fmax(left, right)  # one side empty: high == low, no step
        # each plateau's own change, end to end: a steady slope changes there as it does between them
        inner_left = d[:, span - k : cols - span - k] - d[:, 0 : cols - 2 * span]
        inner_right = d[:, span + span : cols] - d[:, span + k : cols - span + k]
        with np.errstate(invalid="ignore"):
            step = high - low
            flat = self.flat_share * step
            out[:, span : cols - span] = (
                (step > self.step_px)
                & (centre > low + self.margin_px)
                & (centre < high - self.margin_px)
                & (np.abs(inner_left) <= flat)
                & (np.abs(inner_right) <= flat)
            )
        return out

    def apply(self, disparity: F32) -> F32:
        """A copy of the disparity with ramp pixels set to NaN."""
        out = np.array(disparity, dtype=np.float32, copy=True)
        out[self.mask(out)] = np.nan
        return out
