"""Latency and throughput read off the timing trails messages carry (ARCHITECTURE.md).

Every stage appends ``(stage, start_ns, end_ns)`` in wall-clock time and a joining stage carries
the union of its inputs' trails, so the tracker's Obstacles message alone holds the whole path of
a frame: camera_replay's publish, each stage's work, and the tracker's output time.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from common.messages import Timing

#: service names, in pipeline order; other stage names found in trails are reported after them.
STAGES: tuple[str, ...] = ("camera_replay", "stereo_depth", "odometry", "voxel_mapper", "tracker")
SOURCE_STAGE = "camera_replay"
SINK_STAGE = "tracker"


def _percentiles(values_ms: list[float]) -> dict[str, float]:
    arr = np.asarray(values_ms, dtype=np.float64)
    return {"p50": float(np.percentile(arr, 50)), "p95": float(np.percentile(arr, 95))}


def stage_durations_ms(trails: Mapping[int, list[Timing]]) -> dict[str, dict[int, float]]:
    """Per stage, per frame: milliseconds the stage spent (its longest entry if it ran twice)."""
    out: dict[str, dict[int, float]] = {}
    for fid, trail in trails.items():
        for stage, start, end in trail:
            per_frame = out.setdefault(stage, {})
            per_frame[fid] = max(per_frame.get(fid, 0.0), (end - start) / 1e6)
    order = {name: i for i, name in enumerate(STAGES)}
    return dict(sorted(out.items(), key=lambda kv: (order.get(kv[0], len(STAGES)), kv[0])))


def _entry(trail: list[Timing], stage: str) -> Timing | None:
    return next((t for t in trail if t[0] == stage), None)


def end_to_end_ms(sink_trails: Mapping[int, list[Timing]]) -> dict[int, float]:
    """Replay publish (camera_replay's start) to tracker output (its end), per frame.

    A trail without a camera_replay entry (a run fed without the replay service) starts at its
    earliest entry instead.
    """
    out: dict[int, float] = {}
    for fid, trail in sink_trails.items():
        sink = _entry(trail, SINK_STAGE)
        if sink is None or not trail:
            continue
        source = _entry(trail, SOURCE_STAGE)
        start = source[1] if source is not None else min(t[1] for t in trail)
        out[fid] = (sink[2] - start) / 1e6
    return out


def latency_ms(
    trails: Mapping[int, list[Timing]], sink_trails: Mapping[int, list[Timing]]
) -> dict[str, dict[str, float | None]] | None:
    """``{"<stage>": {"p50", "p95"}, "end_to_end": {...}}``; None when no message has a trail."""
    stages = stage_durations_ms(trails)
    if not stages:
        return None
    result: dict[str, dict[str, float | None]] = {
        stage: dict(_percentiles(list(per_frame.values()))) for stage, per_frame in stages.items()
    }
    e2e = end_to_end_ms(sink_trails)
    result["end_to_end"] = dict(_percentiles(list(e2e.values()))) if e2e else {"p50": None, "p95": None}
    return result


def throughput_hz(sink_trails: Mapping[int, list[Timing]]) -> float | None:
    """Sustained output rate: tracker outputs per second between the first and the last one.

    Counted as intervals ((n - 1) / span) so that two outputs 0.1 s apart read 10 Hz.
    """
    ends = sorted(entry[2] for trail in sink_trails.values() if (entry := _entry(trail, SINK_STAGE)) is not None)
    if len(ends) < 2 or ends[-1] <= ends[0]:
        return None
    return (len(ends) - 1) / ((ends[-1] - ends[0]) / 1e9)
