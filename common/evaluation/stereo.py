"""KITTI's D1 disparity error for one frame, with the devkit's background interpolation.

D1-all charges a method for the pixels it leaves empty, but not as if they were infinitely wrong:
KITTI's devkit (``io_disp.h``, ``interpolateBackground``) first fills each gap with the smaller
(farther) of the two disparities bounding it, which is what a careful hole filler would do behind
an occluding edge. Reproducing that exactly keeps our figures comparable with published ones.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from common.errors import InputError

F32 = npt.NDArray[np.float32]

#: a pixel is bad when off by more than this many pixels ...
ABS_THRESHOLD_PX: float = 3.0
#: ... and by more than this share of the true disparity (KITTI 2015's D1).
REL_THRESHOLD: float = 0.05


def valid_mask(disp: npt.NDArray[np.floating]) -> npt.NDArray[np.bool_]:
    """Pixels holding a disparity: finite and positive (NaN and <= 0 mean "no value")."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(disp) & (disp > 0)


def _fill_along_rows(disp: F32, valid: npt.NDArray[np.bool_]) -> F32:
    """Interior gaps take min(left, right neighbour value); row ends extend the nearest value."""
    height, width = disp.shape
    cols = np.broadcast_to(np.arange(width), (height, width))
    prev_idx = np.maximum.accumulate(np.where(valid, cols, -1), axis=1)
    next_idx = np.flip(np.minimum.accumulate(np.flip(np.where(valid, cols, width), axis=1), axis=1), axis=1)
    rows = np.arange(height)[:, None]
    prev_val = np.where(prev_idx >= 0, disp[rows, np.clip(prev_idx, 0, width - 1)], np.nan)
    next_val = np.where(next_idx < width, disp[rows, np.clip(next_idx, 0, width - 1)], np.nan)
    both = (prev_idx >= 0) & (next_idx < width)
    filled = np.where(both, np.fmin(prev_val, next_val), np.where(prev_idx >= 0, prev_val, next_val))
    return np.where(valid, disp, filled).astype(np.float32)


def interpolate_background(disp: npt.NDArray[np.floating]) -> F32:
    """A copy of ``disp`` with every empty pixel filled as KITTI's devkit does.

    Rows first (gaps and row ends), then columns, but only upwards from the first filled row and
    downwards from the last: an empty row between filled rows stays empty, as in the devkit.
    Empty pixels are NaN in the result.
    """
    arr = np.asarray(disp, dtype=np.float32)
    if arr.ndim != 2:
        raise InputError(f"disparity must be 2-D, got shape {arr.shape}")
    valid = valid_mask(arr)
    clean = np.where(valid, arr, np.nan).astype(np.float32)
    rows_filled = _fill_along_rows(clean, valid)
    full_rows = np.nonzero(valid.any(axis=1))[0]
    if full_rows.size == 0:
        return rows_filled
    top, bottom = int(full_rows[0]), int(full_rows[-1])
    rows_filled[:top] = rows_filled[top]
    rows_filled[bottom + 1 :] = rows_filled[bottom]
    return rows_filled


def bad_pixels(est: npt.NDArray[np.floating], truth: npt.NDArray[np.floating]) -> npt.NDArray[np.bool_]:
    """D1 outliers: off by > 3 px and > 5 % of the truth; a missing estimate is bad."""
    with np.errstate(invalid="ignore"):
        err = np.abs(est.astype(np.float64) - truth.astype(np.float64))
        bad = (err > ABS_THRESHOLD_PX) & (err > REL_THRESHOLD * np.abs(truth))
    return bad | ~np.isfinite(est)


def _pct(part: int, whole: int) -> float | None:
    return 100.0 * part / whole if whole else None


def d1_frame(est: np.ndarray, truth: np.ndarray) -> dict[str, float | None]:
    """``d1_all_pct`` (after background interpolation), ``d1_est_pct``, ``density_pct``.

    Shares are of the truth's valid pixels; a share whose denominator is 0 is None.
    """
    est_arr = np.asarray(est)
    truth_arr = np.asarray(truth)
    if est_arr.shape != truth_arr.shape:
        raise InputError(f"estimated disparity {est_arr.shape} and truth {truth_arr.shape} differ in size")
    truth_valid = valid_mask(truth_arr)
    est_valid = valid_mask(est_arr) & truth_valid
    n_truth = int(truth_valid.sum())
    n_est = int(est_valid.sum())
    t = truth_arr[truth_valid]
    bad_est = int(bad_pixels(est_arr[est_valid], truth_arr[est_valid]).sum())
    bad_all = int(bad_pixels(interpolate_background(est_arr)[truth_valid], t).sum())
    return {
        "d1_all_pct": _pct(bad_all, n_truth),
        "d1_est_pct": _pct(bad_est, n_est),
        "density_pct": _pct(n_est, n_truth),
    }
