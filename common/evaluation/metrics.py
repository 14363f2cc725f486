"""The obstacle figures of EVALUATION.md, from frames already matched in the vehicle frame.

Per-frame figures (the paper's Table I, speed, stationary recall, precision) skip a warm-up and
give each object a grace period after it first becomes countable, so that any tracker has had the
chance to accept it and estimate a speed; per-track figures use every frame. A detection matched
to an ignored object (in between speed classes, not visible, outside the volume, in its grace
period) counts nowhere, so doing the right thing on a hard case is never punished.

A detection the one-to-one assignment leaves over but that lies on an object (a long wall seen
as several obstacles) is not a phantom for ``obstacles``; labelled moving it is still a false
positive of the moving figures, as it matches no moving object.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from common.evaluation.matching import DetectionView, FrameMatch, TruthView

#: frames at the start of a run left out of per-frame figures.
WARMUP_FRAMES: int = 10
#: counted frames of each object left out of per-frame figures.
GRACE_FRAMES: int = 5
#: a stationary track labelled moving this many frames in a row is a false moving track.
FALSE_MOVING_RUN: int = 3


def share(part: int | float, whole: int | float, scale: float = 1.0) -> float | None:
    """``part / whole`` (times ``scale``), or None when nothing was there to share."""
    return scale * part / whole if whole else None


def grace_ids(frames: list[FrameMatch], grace: int = GRACE_FRAMES) -> list[set[int]]:
    """Per frame, the ids of counted objects still within their first ``grace`` counted frames."""
    seen: dict[int, int] = {}
    out: list[set[int]] = []
    for frame in frames:
        young: set[int] = set()
        for t in frame.truths:
            if t.counted:
                seen[t.id] = seen.get(t.id, 0) + 1
                if seen[t.id] <= grace:
                    young.add(t.id)
        out.append(young)
    return out


def scored_class(truth: TruthView, young: set[int]) -> str:
    """Class of a truth in per-frame figures: moving, stationary or ignored."""
    if not truth.counted or truth.id in young or truth.motion == "between":
        return "ignored"
    return truth.motion


@dataclass
class Tally:
    """Per-frame outcomes summed over the frames after warm-up."""

    frames: int = 0
    tp: int = 0
    fp: int = 0
    fn: int = 0
    speed_errors: list[float] = field(default_factory=list)
    speed_truths: list[int] = field(default_factory=list)  # the object each speed error is of
    stationary: int = 0
    stationary_matched: int = 0
    stationary_moving: int = 0
    matched: int = 0
    phantoms: int = 0

    def add_frame(self, frame: FrameMatch, young: set[int]) -> None:
        self.frames += 1
        det_of = frame.detection_of()
        for d, det in enumerate(frame.detections):
            truth = frame.truth_of(d)
            if truth is None:
                self._add_unmatched(det, frame, d, young)
                continue
            cls = scored_class(truth, young)
            if cls == "ignored":
                continue
            self.matched += 1
            if det.moving and cls == "moving":
                self.tp += 1
                self.speed_errors.append(float(np.linalg.norm(det.velocity - truth.velocity)))
                self.speed_truths.append(truth.id)
            elif det.moving:
                self.fp += 1
        for t, truth in enumerate(frame.truths):
            cls = scored_class(truth, young)
            det_index = det_of.get(t)
            det = frame.detections[det_index] if det_index is not None else None
            if cls == "moving" and (det is None or not det.moving):
                self.fn += 1
            elif cls == "stationary":
                self.stationary += 1
                self.stationary_matched += det is not None
                self.stationary_moving += det is not None and det.moving

    def _add_unmatched(self, det: DetectionView, frame: FrameMatch, d: int, young: set[int]) -> None:
        """A detection the one-to-one assignment left over.

        On nothing it is a phantom. Inside the grown box of an object already taken (a second
        piece of a split wall or car) it is no phantom, but labelled moving it still matches no
        moving object. Only on ignored objects, it counts nowhere.
        """
        if det.ignored:
            return
        classes = {scored_class(frame.truths[j], young) for j in frame.near[d]} if frame.near else set()
        if classes and classes <= {"ignored"}:
            return
        if classes:
            self.matched += 1
        else:
            self.phantoms += 1
        self.fp += det.moving


def tally(frames: list[FrameMatch], warmup: int = WARMUP_FRAMES) -> Tally:
    total = Tally()
    for frame, young in list(zip(frames, grace_ids(frames), strict=True))[warmup:]:
        total.add_frame(frame, young)
    return total


def moving_figures(t: Tally) -> dict[str, float | int | None]:
    events = t.tp + t.fp + t.fn
    return {
        "tp": t.tp,
        "fp": t.fp,
        "fn": t.fn,
        "tp_pct": share(t.tp, events, 100.0),
        "fp_pct": share(t.fp, events, 100.0),
        "fn_pct": share(t.fn, events, 100.0),
        "precision": share(t.tp, t.tp + t.fp),
        "recall": share(t.tp, t.tp + t.fn),
    }


def speed_figures(t: Tally) -> dict[str, float | int] | None:
    if not t.speed_errors:
        return None
    errors = np.asarray(t.speed_errors)
    return {
        "rmse_mps": float(np.sqrt(np.mean(errors**2))),
        "median_mps": float(np.median(errors)),
        "pairs": len(t.speed_errors),
    }


def stationary_figures(t: Tally) -> dict[str, float | None] | None:
    if not t.stationary:
        return None
    return {
        "recall": share(t.stationary_matched, t.stationary),
        "mislabelled_moving_pct": share(t.stationary_moving, t.stationary_matched, 100.0),
    }


def obstacle_figures(t: Tally) -> dict[str, float | None]:
    return {
        "precision": share(t.matched, t.matched + t.phantoms),
        "phantoms_per_frame": share(t.phantoms, t.frames),
    }


def _labelled_moving(frame: FrameMatch) -> dict[int, int]:
    """Truth id -> obstacle id for the truths matched by a detection labelled moving."""
    return {frame.truths[t].id: frame.detections[d].id for d, t in frame.pairs.items() if frame.detections[d].moving}


@dataclass
class MovingTrack:
    """A moving ground-truth track as the per-track figure sees it (every frame, no warm-up)."""

    counted: list[int] = field(default_factory=list)  # frames it was counted in
    labelled: int | None = None  # the first of them a detection labelled moving matched it in
    matched: int = 0  # how many of them any scored detection matched it in


def moving_tracks(frames: list[FrameMatch]) -> dict[int, MovingTrack]:
    """Each moving ground-truth track by id: when it was counted, first labelled moving, and matched."""
    tracks: dict[int, MovingTrack] = {}
    for frame in frames:
        labelled = _labelled_moving(frame)
        matched = {frame.truths[t].id for t in frame.pairs.values()}
        for truth in frame.truths:
            if truth.counted and truth.motion == "moving":
                track = tracks.setdefault(truth.id, MovingTrack())
                track.counted.append(frame.frame_id)
                track.matched += truth.id in matched
                if truth.id in labelled and track.labelled is None:
                    track.labelled = frame.frame_id
    return tracks


def moving_track_figures(frames: list[FrameMatch]) -> dict[str, float | int | None]:
    """Moving ground-truth tracks: share ever labelled moving, and frames until first labelled."""
    tracks = moving_tracks(frames)
    latencies = [t.labelled - t.counted[0] for t in tracks.values() if t.labelled is not None]
    return {
        "tracks": len(tracks),
        "recall": share(len(latencies), len(tracks)),
        "median_latency_frames": float(np.median(latencies)) if latencies else None,
    }


def stationary_track_figures(frames: list[FrameMatch]) -> dict[str, int]:
    """Stationary ground-truth tracks, and how many were labelled moving 3+ frames in a row."""
    tracks: set[int] = set()
    run: dict[int, int] = {}
    false_moving: set[int] = set()
    for frame in frames:
        labelled = _labelled_moving(frame)
        now: dict[int, int] = {}
        for truth in frame.truths:
            if truth.counted and truth.motion == "stationary":
                tracks.add(truth.id)
                if truth.id in labelled:
                    now[truth.id] = run.get(truth.id, 0) + 1
                    if now[truth.id] >= FALSE_MOVING_RUN:
                        false_moving.add(truth.id)
        run = now
    return {"tracks": len(tracks), "false_moving": len(false_moving)}


def id_switches(frames: list[FrameMatch]) -> int:
    """Times a counted ground-truth object's matched obstacle id changes (gaps do not reset)."""
    last: dict[int, int] = {}
    switches = 0
    for frame in frames:
        for d, t in frame.pairs.items():
            truth = frame.truths[t]
            if not truth.counted:
                continue
            obstacle = frame.detections[d].id
            switches += truth.id in last and last[truth.id] != obstacle
            last[truth.id] = obstacle
    return switches
