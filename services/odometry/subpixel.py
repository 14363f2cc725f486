"""Sub-pixel positions for circle-matched features.

Descriptor matching locates a feature to the pixel; the motion needs better, since a quarter pixel
of disparity at 30 m is a metre of depth. Each match is refined with a single-level Lucas-Kanade
step seeded at its matched position, always tracking the SAME patch (the previous-left one for
the temporal and previous stereo legs, the refined last-left one for the current stereo leg), so
all four observations of a point describe one piece of surface.
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from services.odometry.looming import track_warped

F32 = npt.NDArray[np.float32]

_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 0.01)


def track(
    source: npt.NDArray[np.uint8],
    target: npt.NDArray[np.uint8],
    source_xy: F32,
    guess_xy: F32,
    window: int,
    max_shift: float,
) -> tuple[F32, npt.NDArray[np.bool_]]:
    """Refined target positions of source patches, and which ones converged near their guess."""
    if len(source_xy) == 0:
        return guess_xy.copy(), np.zeros(0, dtype=bool)
    src = np.ascontiguousarray(source_xy, dtype=np.float32).reshape(-1, 1, 2)
    guess = np.ascontiguousarray(guess_xy, dtype=np.float32).reshape(-1, 1, 2).copy()
    out, status, _ = cv2.calcOpticalFlowPyrLK(
        source,
        target,
        src,
        guess,
        winSize=(window, window),
        maxLevel=0,
        criteria=_CRITERIA,
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
    )
    out = out.reshape(-1, 2)
    ok = (status.reshape(-1) == 1) & (np.abs(out - guess_xy).max(axis=1) <= max_shift)
    return out, ok


def refine_circle(
    images: tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8], npt.NDArray[np.uint8], npt.NDArray[np.uint8]],
    xy: tuple[F32, F32, F32, F32],
    window: int,
    max_shift: float,
    stereo: bool = True,
    warps: npt.NDArray[np.float64] | None = None,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """Previous and current observations (u_l, v_l, u_r, v_r), N x 4 each, and a validity mask.

    ``images`` and ``xy`` are ordered (previous-left, previous-right, last-left, last-right).
    Without ``stereo`` the right-image positions stay where the matched corners were detected
    (shifted by the left image's refinement in the current frame). With ``warps`` (N x 2 x 2) the
    temporal leg maps each previous window by its warp first (``looming.track_warped``).
    """
    prev_l, prev_r, cur_l, cur_r = images
    lp, rp, lc, rc = xy
    if warps is None:
        lc_ref, ok_lc = track(prev_l, cur_l, lp, lc, window, max_shift)
    else:
        lc_ref, ok_lc = track_warped(prev_l, cur_l, lp, lc, warps, window, max_shift)
    if stereo:
        rp_ref, ok_rp = track(prev_l, prev_r, lp, rp, window, max_shift)
        rc_ref, ok_rc = track(cur_l, cur_r, lc_ref, rc, window, max_shift)
    else:
        rp_ref, ok_rp = rp, np.ones(len(rp), dtype=bool)
        rc_ref, ok_rc = rc + (lc_ref - lc), np.ones(len(rc), dtype=bool)
    previous = np.concatenate([lp, rp_ref], axis=1).astype(np.float64)
    current = np.concatenate([lc_ref, rc_ref], axis=1).astype(np.float64)
    return previous, current, ok_rp & ok_lc & ok_rc
