"""Where the misses come from: every scored truth-frame by outcome, cluster and class.

The figures of EVALUATION.md say how many moving objects were missed; the first question after
every run is why. Each scored truth-frame is put in one row: what the tracker made of it (found,
a tracked obstacle with the wrong label, no tracked obstacle at all) against what the voxel
mapper gave it (one cluster, several, none of its own but a box shared with a neighbour, nothing).
A moving walker with a "wrong label" and "one" cluster is lost to the tracker's speed estimate; one
with "no track" and "merged" is lost to the mapper. Matching, warm-up and grace are the figures'
own, so the moving rows add up to TP + FN and the stationary rows to the stationary objects scored.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from common.evaluation.inputs import RunInputs
from common.evaluation.matching import FrameMatch, TruthView
from common.evaluation.metrics import WARMUP_FRAMES, grace_ids, scored_class
from common.evaluation.segmentation import CLUSTER_MARGIN_M, box_overlaps, clusters_in_vehicle, inside_box

#: what the tracker made of a scored truth-frame, for a moving and for a stationary object.
FOUND, WRONG_LABEL, NO_TRACK = "found", "wrong label", "no track"
#: what the voxel mapper gave it: one, split and none as segmentation.py counts clusters by centroid;
#: merged when no centroid lies on it but a box overlaps it (it is inside another object's cluster).
SEGMENTS: tuple[str, ...] = ("one", "split", "merged", "none", "no clusters")

F64 = npt.NDArray[np.float64]
Row = tuple[str, str, str]  # (object class, outcome, segment)


@dataclass
class Breakdown:
    """Counts of truth-frames per (class, outcome, segment), for moving and stationary objects."""

    moving: Counter[Row] = field(default_factory=Counter)
    stationary: Counter[Row] = field(default_factory=Counter)

    def total(self, motion: str, outcome: str | None = None) -> int:
        rows: Counter[Row] = getattr(self, motion)
        return sum(n for (_, o, _), n in rows.items() if outcome is None or o == outcome)


Boxes = tuple[F64, F64, F64]  # cluster centroids, box minima, box maxima in the vehicle frame


def segment_of(truth: TruthView, boxes: Boxes | None) -> str:
    """One, split, merged or none (SEGMENTS); "no clusters" when the run recorded none that frame."""
    if boxes is None:
        return "no clusters"
    centroids, lows, highs = boxes
    n = int(inside_box(centroids, truth, CLUSTER_MARGIN_M).sum())
    if n == 1:
        return "one"
    if n > 1:
        return "split"
    overlaps = any(box_overlaps(low, high, truth) for low, high in zip(lows, highs, strict=True))
    return "merged" if overlaps else "none"


def breakdown(run: RunInputs, frames: list[FrameMatch], warmup: int = WARMUP_FRAMES) -> Breakdown:
    """Every moving and stationary truth-frame scored by the figures, in its row."""
    cls_of = {o.id: o.cls for gt in run.truth.values() for o in gt.objects}
    out = Breakdown()
    for frame, young in list(zip(frames, grace_ids(frames), strict=True))[warmup:]:
        det_of = frame.detection_of()
        clusters = run.clusters.get(frame.frame_id)
        boxes = None if clusters is None else clusters_in_vehicle(clusters)
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
    return "\n".join(lines)
