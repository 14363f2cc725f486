"""Disparity beside depth steps: how many background pixels a matcher places between two surfaces.

D1 counts pixels more than 3 px wrong, so it hardly sees what joins a walker to the wall behind
him in the voxel map: background pixels next to a nearer object given disparities between the
object's and the background's, a few tenths to two pixels off. Each is a point in the empty space
between the two surfaces, and a row of them strings voxels along the line of sight from one to
the other (docs/results/voxel.md, "Session 16" and "Session 29"). This module counts them, column
by column away from each step, on the two sides, which differ:

- left of a nearer object (in the left image) lies the band the right camera cannot see; the
  truth leaves it empty, so the background's disparity is read beyond it;
- right of it the background is seen by both cameras; a matcher fattens the object into it (its
  pixels take the object's disparity: the object grows sideways, a few centimetres) or ramps
  across it (points between the two: the smear).

Only *between* counts: a pixel more than ``MARGIN_PX`` nearer than its background and more than
``MARGIN_PX`` farther than the object. Steps are taken in the truth, where a row's disparity
rises by more than ``STEP_PX`` from one column (or from the last one before the hidden band) to
the next, with the nearer side within ``DISPARITY_RANGE`` (the obstacles' depths).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

F32 = npt.NDArray[np.floating]

#: columns counted on each side of a step.
REACH: int = 8
#: a step: the nearer side's disparity this much (px) above the farther side's.
STEP_PX: float = 1.5
#: a pixel is between the two surfaces when more than this (px) from both.
MARGIN_PX: float = 0.5
#: the nearer side's disparity (px) for a step to count: on the synthetic rig (fx * B = 240 px m)
#: 6-30 m, where obstacles are; a frame's own calibration is not needed for a share.
DISPARITY_RANGE: tuple[float, float] = (8.0, 40.0)
#: background pixels are followed this far (px of disparity) from the plateau beside the step.
PLATEAU_PX: float = 0.3
#: the hidden band left of a step is at most this many columns wide (a step of 12 px and more is a
#: near object, outside ``DISPARITY_RANGE``'s interest anyway).
MAX_HIDDEN: int = 12


@dataclass
class EdgeCounts:
    """Per side, per column from the step (0 = next to it): background pixels and those between."""

    hidden: npt.NDArray[np.int64] = field(default_factory=lambda: np.zeros(REACH, np.int64))
    hidden_between: npt.NDArray[np.int64] = field(default_factory=lambda: np.zeros(REACH, np.int64))
    seen: npt.NDArray[np.int64] = field(default_factory=lambda: np.zeros(REACH, np.int64))
    seen_between: npt.NDArray[np.int64] = field(default_factory=lambda: np.zeros(REACH, np.int64))

    def add(self, other: EdgeCounts) -> None:
        for name in ("hidden", "hidden_between", "seen", "seen_between"):
            getattr(self, name)[:] += getattr(other, name)

    def shares(self) -> dict[str, list[float | None]]:
        """Share (%) of background pixels between the surfaces, per column, on each side."""

        def pct(part: npt.NDArray[np.int64], whole: npt.NDArray[np.int64]) -> list[float | None]:
            return [None if w == 0 else 100.0 * float(p) / float(w) for p, w in zip(part, whole, strict=True)]

        return {"hidden_side": pct(self.hidden_between, self.hidden), "seen_side": pct(self.seen_between, self.seen)}


def edge_counts(estimate: F32, truth: F32) -> EdgeCounts:
    """Count one frame (both ``(rows, cols)`` disparity images, NaN or <= 0 where empty)."""
    est = np.asarray(estimate, dtype=np.float32)
    gt = np.asarray(truth, dtype=np.float32)
    out = EdgeCounts()
    if est.shape != gt.shape or gt.ndim != 2 or gt.shape[1] < 2:
        return out
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(gt) & (gt > 0)
    gt = np.where(valid, gt, np.float32(np.nan))
    rows, cols = gt.shape
    r_idx = np.arange(rows)[:, None]
    lo, hi = DISPARITY_RANGE
    # the last valid column at or before each column, and its value (the background left of a step)
    last = np.maximum.accumulate(np.where(valid, np.arange(cols)[None, :], -1), axis=1)
    after = gt[:, 1:]  # column c + 1, for c = 0 .. cols - 2: a rising step's object, a falling one's background
    with np.errstate(invalid="ignore"):
        in_range = (after >= lo) & (after <= hi)
        # rising step: background left of it (through the hidden band), object from column c + 1
        back_col = last[:, :-1]
        back = np.where(back_col >= 0, gt[r_idx, np.maximum(back_col, 0)], np.nan)
        rising = in_range & (after - back > STEP_PX) & (np.arange(cols - 1)[None, :] - back_col <= MAX_HIDDEN)
        # falling step: object ends at column c, background seen by both from c + 1
        obj = gt[:, :-1]
        falling = (obj >= lo) & (obj <= hi) & (obj - after > STEP_PX)
    for k in range(REACH):
        # hidden side: column c - k, judged against the background beyond the band and the object
        cs = np.arange(k, cols - 1)
        rs, cc = np.nonzero(rising[:, cs])
        cc = cs[cc]
        px = est[rs, cc - k]
        fg, bg = after[rs, cc], back[rs, cc]
        out.hidden[k] += len(rs)
        with np.errstate(invalid="ignore"):
            out.hidden_between[k] += int(((px > bg + MARGIN_PX) & (px < fg - MARGIN_PX)).sum())
        # seen side: column c + 1 + k, while it stays on the background's plateau
        cs = np.arange(0, cols - 1 - k)
        rs, cc = np.nonzero(falling[:, cs])
        cc = cs[cc]
        bg_k, bg_0 = gt[rs, cc + 1 + k], gt[rs, cc + 1]
        with np.errstate(invalid="ignore"):
            plateau = np.abs(bg_k - bg_0) < PLATEAU_PX
        rs, cc, bg_k = rs[plateau], cc[plateau], bg_k[plateau]
        px, fg = est[rs, cc + 1 + k], obj[rs, cc]
        out.seen[k] += len(rs)
        with np.errstate(invalid="ignore"):
            out.seen_between[k] += int(((px > bg_k + MARGIN_PX) & (px < fg - MARGIN_PX)).sum())
    return out


#: share of a truth image's pixels holding a disparity for its steps to be read: dense synthetic
#: and Middlebury truth; a projected lidar scan (KITTI, a few per cent) has gaps everywhere.
DENSE_SHARE: float = 0.5


def dense(truth: F32) -> bool:
    """Whether the truth is dense enough to find depth steps in it."""
    with np.errstate(invalid="ignore"):
        return bool((np.isfinite(truth) & (np.asarray(truth) > 0)).mean() >= DENSE_SHARE)


def format_edges(counts: EdgeCounts) -> str:
    """The ``evaluate --why`` table: % of background pixels between the two surfaces, per column."""
    if counts.hidden.sum() + counts.seen.sum() == 0:
        return "stereo beside depth steps: no dense disparity truth with steps in range"
    shares = counts.shares()
    lines = [
        f"stereo beside depth steps (truth rising by > {STEP_PX} px, nearer side {DISPARITY_RANGE[0]:.0f}-"
        f"{DISPARITY_RANGE[1]:.0f} px): % of background pixels between the two surfaces (> {MARGIN_PX} px from both), "
        "by column from the step",
        "  side                      steps  " + "".join(f"{k:>6d}" for k in range(1, REACH + 1)),
    ]
    for name, label, n in (("hidden_side", "beside the hidden band", counts.hidden[0]),
                           ("seen_side", "seen by both cameras", counts.seen[0])):  # fmt: skip
        cells = "".join("     -" if v is None else f"{v:6.1f}" for v in shares[name])
        lines.append(f"  {label:24s} {n:6d}  {cells}")
    return "\n".join(lines)
