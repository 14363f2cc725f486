"""Where the misses come from: every scored truth-frame by outcome, cluster and class.

The figures of EVALUATION.md say how many moving objects were missed; the first question after
every run is why. Each scored truth-frame is put in one row: what the tracker made of it (found,
a tracked obstacle with the wrong label, no tracked obstacle at all) against what the voxel
mapper gave it (one cluster, several, none of its own but a box shared with a neighbour, nothing).
A moving walker with a "wrong label" and "one" cluster is lost to the tracker's speed estimate; one
with "no track" and "merged" is lost to the mapper. Matching, warm-up and grace are the figures'
own, so the moving rows add up to TP + FN and the stationary rows to the stationary objects scored.

Segmentation is scored on more objects than the tracker (every counted object of every frame,
standing or moving), so its own table follows: the counted object-frames per class as
``one_cluster_pct`` counts them, and the one-cluster share by range. Which class, and how far
away, is what says whether the loss is stereo's (thin poles and walkers beyond 22 m, where a pixel
of disparity is metres of range) or the clustering's.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from common.evaluation.inputs import RunInputs
from common.evaluation.matching import FrameMatch, TruthView
from common.evaluation.metrics import WARMUP_FRAMES, grace_ids, scored_class
from common.evaluation.segmentation import box_overlaps, clusters_in_vehicle, clusters_on

#: what the tracker made of a scored truth-frame, for a moving and for a stationary object.
FOUND, WRONG_LABEL, NO_TRACK = "found", "wrong label", "no track"
#: what the voxel mapper gave it: one, split and none as segmentation.py counts clusters by centroid;
#: merged when no centroid lies on it but a box overlaps it (it is inside another object's cluster).
SEGMENTS: tuple[str, ...] = ("one", "split", "merged", "none", "no clusters")

#: how many clusters a counted object has, as segmentation.py counts them for ``one_cluster_pct``.
COUNTS: tuple[str, ...] = ("one", "split", "missed")
#: range bands (m, from the vehicle) of the segmentation table: the upper ends of all but the last.
BANDS_M: tuple[float, ...] = (15.0, 22.0)
BAND_NAMES: tuple[str, ...] = ("< 15 m", "15-22 m", ">= 22 m")

F64 = npt.NDArray[np.float64]
Row = tuple[str, str, str]  # (object class, outcome, segment); segmentation: (class, band, count)


@dataclass
class Breakdown:
    """Counts of truth-frames per (class, outcome, segment), for moving and stationary objects."""

    moving: Counter[Row] = field(default_factory=Counter)
    stationary: Counter[Row] = field(default_factory=Counter)
    segmentation: Counter[Row] = field(default_factory=Counter)  # counted object-frames, every frame

    def total(self, motion: str, outcome: str | None = None) -> int:
        rows: Counter[Row] = getattr(self, motion)
        return sum(n for (_, o, _), n in rows.items() if outcome is None or o == outcome)


Boxes = tuple[F64, F64, F64]  # cluster centroids, box minima, box maxima in the vehicle frame


def segment_of(truth: TruthView, boxes: Boxes | None) -> str:
    """One, split, merged or none (SEGMENTS); "no clusters" when the run recorded none that frame."""
    if boxes is None:
        return "no clusters"
    centroids, lows, highs = boxes
    n = clusters_on(centroids, truth)
    if n == 1:
        return "one"
    if n > 1:
        return "split"
    overlaps = any(box_overlaps(low, high, truth) for low, high in zip(lows, highs, strict=True))
    return "merged" if overlaps else "none"


def breakdown(run: RunInputs, frames: list[FrameMatch], warmup: int = WARMUP_FRAMES) -> Breakdown:
    """Every moving and stationary truth-frame scored by the figures, and every counted object-frame, in its row."""
    cls_of = {o.id: o.cls for gt in run.truth.values() for o in gt.objects}
    boxes_of = {f.frame_id: clusters_in_vehicle(run.clusters[f.frame_id]) for f in frames if f.frame_id in run.clusters}
    out = Breakdown()
    for frame in frames:
        if frame.frame_id not in boxes_of:
            continue
        centroids = boxes_of[frame.frame_id][0]
        for truth in frame.truths:
            if truth.counted:
                n = clusters_on(centroids, truth)
                band = BAND_NAMES[int(np.searchsorted(BANDS_M, np.linalg.norm(truth.center[:2]), side="right"))]
                count = COUNTS[0] if n == 1 else COUNTS[1] if n > 1 else COUNTS[2]
                out.segmentation[(cls_of.get(truth.id, "?"), band, count)] += 1
    for frame, young in list(zip(frames, grace_ids(frames), strict=True))[warmup:]:
        det_of = frame.detection_of()
        boxes = boxes_of.get(frame.frame_id)
        for t, truth in enumerate(frame.truths):
            motion = scored_class(truth, young)
            if motion == "ignored":
                continue
            d = det_of.get(t)
            if d is None:
                outcome = NO_TRACK
            else:
                outcome = FOUND if frame.detections[d].moving == (motion == "moving") else WRONG_LABEL
            row = (cls_of.get(truth.id, "?"), outcome, segment_of(truth, boxes))
            getattr(out, motion)[row] += 1
    return out


def format_breakdown(b: Breakdown) -> str:
    """A table per motion class: one line per object class and outcome, segments across."""
    lines = []
    for motion in ("moving", "stationary"):
        rows: Counter[Row] = getattr(b, motion)
        lines.append(f"{motion} truth-frames by outcome and clusters ({b.total(motion)} scored)")
        lines.append(f"  {'class':<12} {'outcome':<12} " + " ".join(f"{s:>11}" for s in SEGMENTS))
        keys = sorted({(c, o) for c, o, _ in rows}, key=lambda k: (k[0], (FOUND, WRONG_LABEL, NO_TRACK).index(k[1])))
        for cls, outcome in keys:
            counts = " ".join(f"{rows.get((cls, outcome, s), 0):>11}" for s in SEGMENTS)
            lines.append(f"  {cls:<12} {outcome:<12} {counts}")
    if b.segmentation:
        lines.extend(_segmentation_lines(b.segmentation))
    return "\n".join(lines)


def _segmentation_lines(rows: Counter[Row]) -> list[str]:
    """Per class: object-frames, one-cluster %, split, missed, and one-cluster % per range band."""

    def pct(one: int, n: int) -> str:
        return f"{100.0 * one / n:.1f}" if n else "-"

    def count(cls: str | None, band: str | None, what: str | None) -> int:
        return sum(
            n for (c, b, w), n in rows.items()
            if (cls is None or c == cls) and (band is None or b == band) and (what is None or w == what)
        )  # fmt: skip

    total = count(None, None, None)
    lines = [
        f"counted objects by clusters on them ({total} object-frames, one cluster "
        f"{pct(count(None, None, 'one'), total)} %), one-cluster % by range",
        f"  {'class':<12} {'frames':>7} {'one %':>7} {'split':>6} {'missed':>7} "
        + " ".join(f"{b:>8}" for b in BAND_NAMES),
    ]
    for cls in sorted({c for c, _, _ in rows}, key=lambda c: -count(c, None, None)):
        n = count(cls, None, None)
        bands = " ".join(f"{pct(count(cls, b, 'one'), count(cls, b, None)):>8}" for b in BAND_NAMES)
        lines.append(
            f"  {cls:<12} {n:>7} {pct(count(cls, None, 'one'), n):>7} {count(cls, None, 'split'):>6} "
            f"{count(cls, None, 'missed'):>7} {bands}"
        )
    return lines
