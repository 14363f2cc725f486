"""Pixels on the ramp a matcher leaves across a depth step: optionally dropped from the point cloud, or moved.

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

Leaving the pixels out (``stereo.ramp_snap_ratio = 0`` with ``ramp_flat_share = 0.15``) gave
synthetic scenes fewer merged clusters and phantom obstacles, but KITTI tracking 0001 more false
moving tracks, mostly on trees and hedges (docs/results/voxel.md, "Session 16"). The published
disparity image stays the matcher's own either way, as with the rig's bias correction: only the
cloud's pixels are moved or left out.

Snapping (``stereo.ramp_snap_ratio`` > 0) keeps the pixels instead: one whose colour is clearly
nearer one plateau's (by that factor, L1 over the channels, against the plateau's own columns)
takes that plateau's disparity, so a grey pixel beside a red pole goes back onto the grey wall
behind it and the cloud keeps its density; one that looks like neither stays as matched. Beside a
step, most such pixels lie where the right camera cannot see (``evaluate --why`` counts them per
column and side). On a slanted surface of one colour both plateaus look alike and nothing moves,
so the colour does the flatness test's work and ``ramp_flat_share = 0`` turns that test off.
Session 29 measured it and left it off: it raised synthetic urban's one-cluster share but called
more standing things moving on KITTI tracking 0001, on tree crowns the tracker now never calls
moving (its floor rule). Measured again in session 46 on 61 runs, at a ratio of 0.3 it raises the
one-cluster share on 13 of 14 scenario sets and leaves the tracker's figures about even, so it is
on (docs/results/voxel.md, "Session 46").
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
    flat_share: float = 0.15  # 0: no flatness test
    snap_ratio: float = 0.0  # > 0: ramp pixels move onto the plateau of clearly nearer colour instead of leaving

    def __post_init__(self) -> None:
        if (self.reach < 1 or self.width < 1 or self.step_px <= 0.0 or self.margin_px < 0.0 or self.flat_share < 0.0
                or not 0.0 <= self.snap_ratio <= 1.0):  # fmt: skip
            raise ConfigError(
                "stereo.ramp_reach_px and ramp_width_px must be >= 1, ramp_step_px > 0, ramp_margin_px and "
                f"ramp_flat_share >= 0, and ramp_snap_ratio within 0..1; got {self}"
            )

    def mask(self, disparity: F32) -> npt.NDArray[np.bool_]:
        """True for pixels strictly between the two plateaus of a depth step (see the module text)."""
        return self._ramp(np.asarray(disparity, dtype=np.float32))[0]

    def _ramp(self, d: F32) -> tuple[npt.NDArray[np.bool_], F32, F32]:
        """The ramp mask and, for every pixel, the left and right plateaus' mean disparity (NaN at the borders)."""
        cols = d.shape[1]
        k, w = self.reach, self.width
        out = np.zeros(d.shape, dtype=bool)
        left_full = np.full(d.shape, np.nan, dtype=np.float32)
        right_full = np.full(d.shape, np.nan, dtype=np.float32)
        span = k + w - 1  # the farthest column either plateau reaches
        if cols <= 2 * span:
            return out, left_full, right_full
        finite = np.isfinite(d)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = _runs(np.where(finite, d, np.float32(0.0)), w) / _runs(finite.astype(np.float32), w)
        # pixel u (span <= u < cols - span): left plateau = run starting at u - span, right = at u + k
        left = mean[:, 0 : cols - 2 * span]
        right = mean[:, span + k : cols - w + 1]
        centre = d[:, span : cols - span]
        low, high = np.fmin(left, right), np.fmax(left, right)  # one side empty: high == low, no step
        with np.errstate(invalid="ignore"):
            step = high - low
            ramp = (step > self.step_px) & (centre > low + self.margin_px) & (centre < high - self.margin_px)
            if self.flat_share > 0.0:
                # each plateau's own change, end to end: a steady slope changes there as it does between them
                inner_left = d[:, span - k : cols - span - k] - d[:, 0 : cols - 2 * span]
                inner_right = d[:, span + span : cols] - d[:, span + k : cols - span + k]
                flat = self.flat_share * step
                ramp &= (np.abs(inner_left) <= flat) & (np.abs(inner_right) <= flat)
        out[:, span : cols - span] = ramp
        left_full[:, span : cols - span] = left
        right_full[:, span : cols - span] = right
        return out, left_full, right_full

    def apply(self, disparity: F32, image: npt.NDArray[np.uint8] | None = None) -> F32:
        """A copy of the disparity with ramp pixels set to NaN, or with ``snap_ratio`` moved onto a plateau.

        Snapping needs the ``image`` the disparity belongs to (rows x cols x channels).
        """
        out = np.array(disparity, dtype=np.float32, copy=True)
        ramp, left, right = self._ramp(out)
        if self.snap_ratio <= 0.0:
            out[ramp] = np.nan
            return out
        if not ramp.any():  # nothing to move; an image narrower than the plateaus has no colour runs either
            return out
        if image is None or image.shape[:2] != out.shape:
            raise ConfigError("stereo.ramp_snap_ratio needs the image the disparity belongs to")
        to_left, to_right = self._nearer_colour(ramp, np.asarray(image))
        out[to_left] = left[to_left]
        out[to_right] = right[to_right]
        return out

    def _nearer_colour(
        self, ramp: npt.NDArray[np.bool_], image: npt.NDArray[np.uint8]
    ) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
        """Ramp pixels whose colour is clearly nearer the left plateau's, and those nearer the right one's.

        Colours are compared over the plateaus' own columns (L1 over the channels); "clearly" is
        nearer by the factor ``snap_ratio``, so a pixel on a slanted surface of one colour, whose
        two plateaus look alike, stays where the matcher put it. Only the ramp's own pixels are
        looked at (a few per cent of the frame): the whole image's column runs cost 15-20 ms.
        """
        rows, cols = ramp.shape
        k, w = self.reach, self.width
        span = k + w - 1
        img = image.reshape(rows, cols, -1)
        r, c = np.nonzero(ramp)  # the mask is False within span of either side, so every run is inside

        def plateau(first: npt.NDArray[np.intp]) -> F32:
            total = np.zeros((len(r), img.shape[2]), dtype=np.float32)
            for o in range(w):
                total += img[r, first + o]
            return total / np.float32(w)

        centre = img[r, c].astype(np.float32)
        off_left = np.abs(centre - plateau(c - span)).sum(axis=1)
        off_right = np.abs(centre - plateau(c + k)).sum(axis=1)
        to_left, to_right = np.zeros_like(ramp), np.zeros_like(ramp)
        to_left[r, c] = off_left < self.snap_ratio * off_right
        to_right[r, c] = off_right < self.snap_ratio * off_left
        return to_left, to_right


def _runs(values: npt.NDArray[np.float32], width: int) -> npt.NDArray[np.float32]:
    """Sums over every run of ``width`` columns: column j of the result covers columns j .. j + width - 1."""
    cols = values.shape[1]
    run = np.zeros((values.shape[0], cols - width + 1, *values.shape[2:]), dtype=np.float32)
    for o in range(width):
        run += values[:, o : cols - width + 1 + o]
    return run
