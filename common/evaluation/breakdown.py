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
of disparity is metres of range) or the clustering's. A missed object is then told by the clusters
whose boxes reach it: one of its own whose centroid the smear along the line of sight moved out of
its box, only clusters that also reach another counted object (merged), or none at all (dropped as
noise, or never seen). The three want different remedies: the first a centroid that the smear
cannot move, the second a cut, the third a lower noise limit or better stereo.

Then the scored truth-frames whose box shares volume with another object's: a synthetic street
that puts a bin inside a kiosk or rides a cyclist through a pole scores a miss no pipeline could
avoid, and this says how much of the figures that is.

Then the moving objects never labelled moving, which ``moving_tracks.recall`` counts over every
frame, warm-up included: when in the run each was counted, and in how many of those frames a
tracked obstacle matched it. One counted only in a run's first or last few frames (``EDGE_FRAMES``)
left little time: a track born in its first counted frame is accepted in its second and may be
labelled moving from its third (this tracker's defaults), two frames at most, and only if its speed
is sure by then.

Last, the speed error object by object. The RMSE pools every true moving frame, and on a street a
few objects hold most of its squared error: a lead car changing lane followed at its rear face, a
cyclist read through metres of range noise, a track that slid from one object onto another
(docs/results/tracking.md, "Session 52"). Which they are says what to mend.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from common.evaluation.inputs import RunInputs
from common.evaluation.matching import FrameMatch, TruthView
from common.evaluation.metrics import WARMUP_FRAMES, MovingTrack, grace_ids, moving_tracks, scored_class, tally
from common.evaluation.segmentation import box_overlaps, clusters_in_vehicle, clusters_on, truths_share_volume
from common.messages import OPEN_CLASSES

#: what the tracker made of a scored truth-frame, for a moving and for a stationary object.
FOUND, WRONG_LABEL, NO_TRACK = "found", "wrong label", "no track"
#: what the voxel mapper gave it: one, split and none as segmentation.py counts clusters by centroid;
#: merged when no centroid lies on it but a box overlaps it (it is inside another object's cluster).
SEGMENTS: tuple[str, ...] = ("one", "split", "merged", "none", "no clusters")

#: how many clusters a counted object has, as segmentation.py counts them for ``one_cluster_pct``.
COUNTS: tuple[str, ...] = ("one", "split", "missed")
#: why a counted object has no cluster centred on it (``missed``), as ``missed_kind`` tells them.
MISSED_KINDS: tuple[str, ...] = ("own, off centre", "shared", "untouched")
#: range bands (m, from the vehicle) of the segmentation table: the upper ends of all but the last.
BANDS_M: tuple[float, ...] = (15.0, 22.0)
BAND_NAMES: tuple[str, ...] = ("< 15 m", "15-22 m", ">= 22 m")
#: a moving object counted only within a run's first or last this many frames is told apart: a track
#: born in its first counted frame could be labelled moving in two of them at most (from its third).
EDGE_FRAMES: int = 4
#: where in the run a never-labelled moving object was counted (``where_in_run``).
WHERE: tuple[str, ...] = ("first frames", "last frames", "mid-run")

F64 = npt.NDArray[np.float64]
Row = tuple[str, str, str]  # (object class, outcome, segment); segmentation: (class, band, count)


@dataclass
class Breakdown:
    """Counts of truth-frames per (class, outcome, segment), for moving and stationary objects."""

    moving: Counter[Row] = field(default_factory=Counter)
    stationary: Counter[Row] = field(default_factory=Counter)
    segmentation: Counter[Row] = field(default_factory=Counter)  # counted object-frames, every frame
    missed: Counter[tuple[str, str]] = field(default_factory=Counter)  # (class, MISSED_KINDS) of the missed ones
    inside: Counter[Row] = field(default_factory=Counter)  # (motion, class, outcome) of those sharing volume
    speed: dict[tuple[int, str], list[float]] = field(default_factory=dict)  # (id, class): its speed errors (m/s)
    moving_tracks: int = 0  # moving objects counted in some frame, as ``moving_tracks.tracks``
    unlabelled: list[tuple[int, str, MovingTrack, str]] = field(default_factory=list)  # (id, class, track, WHERE)

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


def missed_kind(truth: TruthView, boxes: Boxes, counted: list[TruthView]) -> str:
    """For an object no centroid lies on: whether a cluster of its own reaches it, only shared ones, or none.

    A cluster is its own when its box reaches no other counted object (walls and buildings are not
    counted, so a pole's cluster smeared onto the facade behind it is still its own).
    """
    _, lows, highs = boxes
    touching = [k for k in range(len(lows)) if box_overlaps(lows[k], highs[k], truth)]
    if not touching:
        return MISSED_KINDS[2]
    others = [u for u in counted if u is not truth]
    own = any(not any(box_overlaps(lows[k], highs[k], u) for u in others) for k in touching)
    return MISSED_KINDS[0] if own else MISSED_KINDS[1]


def where_in_run(counted: list[int], first: int, last: int) -> str:
    """Whether frames ``counted`` all lie within ``EDGE_FRAMES`` of the run's first or last frame, or not."""
    if max(counted) < first + EDGE_FRAMES:
        return WHERE[0]
    if min(counted) > last - EDGE_FRAMES:
        return WHERE[1]
    return WHERE[2]


def breakdown(run: RunInputs, frames: list[FrameMatch], warmup: int = WARMUP_FRAMES) -> Breakdown:
    """Every moving and stationary truth-frame scored by the figures, and every counted object-frame, in its row."""
    cls_of = {o.id: o.cls for gt in run.truth.values() for o in gt.objects}
    boxes_of = {f.frame_id: clusters_in_vehicle(run.clusters[f.frame_id]) for f in frames if f.frame_id in run.clusters}
    out = Breakdown()
    for frame in frames:
        if frame.frame_id not in boxes_of:
            continue
        boxes = boxes_of[frame.frame_id]
        counted = [t for t in frame.truths if t.counted]
        for truth in counted:
            n = clusters_on(boxes[0], truth)
            band = BAND_NAMES[int(np.searchsorted(BANDS_M, np.linalg.norm(truth.center[:2]), side="right"))]
            count = COUNTS[0] if n == 1 else COUNTS[1] if n > 1 else COUNTS[2]
            out.segmentation[(cls_of.get(truth.id, "?"), band, count)] += 1
            if n == 0:
                out.missed[(cls_of.get(truth.id, "?"), missed_kind(truth, boxes, counted))] += 1
    for frame, young in list(zip(frames, grace_ids(frames), strict=True))[warmup:]:
        det_of = frame.detection_of()
        boxes = boxes_of.get(frame.frame_id)
        solid = [u for u in frame.truths if cls_of.get(u.id) not in OPEN_CLASSES]
        for t, truth in enumerate(frame.truths):
            motion = scored_class(truth, young)
            if motion == "ignored":
                continue
            d = det_of.get(t)
            if d is None:
                outcome = NO_TRACK
            else:
                outcome = FOUND if frame.detections[d].moving == (motion == "moving") else WRONG_LABEL
            cls = cls_of.get(truth.id, "?")
            getattr(out, motion)[(cls, outcome, segment_of(truth, boxes))] += 1
            if cls not in OPEN_CLASSES and any(u is not truth and truths_share_volume(truth, u) for u in solid):
                out.inside[(motion, cls, outcome)] += 1
    tracks = moving_tracks(frames)
    out.moving_tracks = len(tracks)
    for oid, track in sorted(tracks.items()):
        if track.labelled is None:
            where = where_in_run(track.counted, frames[0].frame_id, frames[-1].frame_id)
            out.unlabelled.append((oid, cls_of.get(oid, "?"), track, where))
    pairs = tally(frames, warmup)  # the speed figure's own pairs, so the rows add up to its RMSE
    for oid, error in zip(pairs.speed_truths, pairs.speed_errors, strict=True):
        out.speed.setdefault((oid, cls_of.get(oid, "?")), []).append(error)
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
    if b.missed:
        lines.extend(_missed_lines(b.missed))
    if b.inside:
        lines.extend(_inside_lines(b.inside))
    if b.unlabelled:
        lines.extend(_unlabelled_lines(b.unlabelled, b.moving_tracks))
    if b.speed:
        lines.extend(_speed_lines(b.speed))
    return "\n".join(lines)


def _unlabelled_lines(rows: list[tuple[int, str, MovingTrack, str]], tracks: int) -> list[str]:
    """Per moving object never labelled moving: counted frames, their span, frames matched, where in the run."""
    lines = [
        f"moving objects never labelled moving ({len(rows)} of {tracks}): frames counted, the first and last, "
        "frames a tracked obstacle matched it, where in the run",
        f"  {'id':>6} {'class':<12} {'counted':>7} {'frames':>9} {'matched':>7}  where",
    ]
    for oid, cls, track, where in rows:
        span = f"{track.counted[0]}-{track.counted[-1]}"
        lines.append(f"  {oid:>6} {cls:<12} {len(track.counted):>7} {span:>9} {track.matched:>7}  {where}")
    edge = sum(where != WHERE[2] for *_, where in rows)
    lines.append(f"  {edge} of {len(rows)} counted only within {EDGE_FRAMES} frames of the run's start or end")
    return lines


#: objects the speed table lists, largest squared error first; the rest are summed in one line.
SPEED_ROWS: int = 10


def _speed_lines(errors: dict[tuple[int, str], list[float]]) -> list[str]:
    """Per object: true moving frames, squared speed error (m^2/s^2) and its share, RMS and worst error."""
    rows = sorted(((float(np.square(e).sum()), oid, cls, e) for (oid, cls), e in errors.items()), key=lambda r: -r[0])
    total = max(sum(r[0] for r in rows), 1e-12)
    pairs = sum(len(r[3]) for r in rows)
    lines = [
        f"speed error by object ({pairs} true moving frames, RMSE {np.sqrt(total / pairs):.2f} m/s, "
        f"squared error {total:.1f} m^2/s^2)",
        f"  {'id':>6} {'class':<12} {'frames':>7} {'sq. error':>10} {'share %':>8} {'RMS':>6} {'worst':>6}",
    ]
    for sq, oid, cls, e in rows[:SPEED_ROWS]:
        lines.append(
            f"  {oid:>6} {cls:<12} {len(e):>7} {sq:>10.2f} {100.0 * sq / total:>8.1f} "
            f"{np.sqrt(sq / len(e)):>6.2f} {max(e):>6.2f}"
        )
    rest = rows[SPEED_ROWS:]
    if rest:
        sq, n = sum(r[0] for r in rest), sum(len(r[3]) for r in rest)
        lines.append(f"  {'':>6} {f'{len(rest)} more':<12} {n:>7} {sq:>10.2f} {100.0 * sq / total:>8.1f}")
    return lines


def _inside_lines(rows: Counter[Row]) -> list[str]:
    """Per motion and class: the scored truth-frames inside another object's box, by outcome."""
    outcomes = (FOUND, WRONG_LABEL, NO_TRACK)
    lines = [
        f"scored truth-frames whose box shares volume with another object's ({sum(rows.values())}): "
        "the scene put them inside each other",
        f"  {'motion':<12} {'class':<12} " + " ".join(f"{o:>11}" for o in outcomes),
    ]
    for motion, cls in sorted({(m, c) for m, c, _ in rows}):
        lines.append(f"  {motion:<12} {cls:<12} " + " ".join(f"{rows.get((motion, cls, o), 0):>11}" for o in outcomes))
    return lines


def _missed_lines(rows: Counter[tuple[str, str]]) -> list[str]:
    """Per class: the missed object-frames by what the clusters reaching them are (MISSED_KINDS)."""
    total = sum(rows.values())
    lines = [
        f"missed objects by the clusters reaching them ({total} object-frames): a cluster of its own off centre, "
        "only clusters shared with another object, none",
        f"  {'class':<12} {'missed':>7} " + " ".join(f"{k:>16}" for k in MISSED_KINDS),
    ]
    for cls in sorted({c for c, _ in rows}, key=lambda c: -sum(n for (k, _), n in rows.items() if k == c)):
        counts = [rows.get((cls, kind), 0) for kind in MISSED_KINDS]
        lines.append(f"  {cls:<12} {sum(counts):>7} " + " ".join(f"{n:>16}" for n in counts))
    return lines


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
