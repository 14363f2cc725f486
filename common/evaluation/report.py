"""The evaluation as a table a person reads; the JSON object stays the machine interface."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

Figures = dict[str, Any]


def num(value: float | int | None, spec: str = ".3f", unit: str = "") -> str:
    """A figure formatted, or "-" for null (a missing input or an empty denominator)."""
    return "-" if value is None else f"{value:{spec}}{unit}"


def _moving(m: Figures) -> str:
    return (
        f"TP {m['tp']} ({num(m['tp_pct'], '.1f', ' %')})  FP {m['fp']} ({num(m['fp_pct'], '.1f', ' %')})  "
        f"FN {m['fn']} ({num(m['fn_pct'], '.1f', ' %')})  precision {num(m['precision'])}  recall {num(m['recall'])}"
    )


def _moving_tracks(m: Figures) -> str:
    return (
        f"{m['tracks']} tracks, recall {num(m['recall'])}, "
        f"median latency {num(m['median_latency_frames'], '.1f', ' frames')}"
    )


def _stationary_tracks(m: Figures) -> str:
    return f"{m['tracks']} tracks, {m['false_moving']} labelled moving 3+ frames in a row"


def _speed(m: Figures) -> str:
    rmse, median = num(m["rmse_mps"], ".2f", " m/s"), num(m["median_mps"], ".2f", " m/s")
    return f"RMSE {rmse}, median {median} over {m['pairs']} pairs"


def _stationary(m: Figures) -> str:
    return f"recall {num(m['recall'])}, {num(m['mislabelled_moving_pct'], '.1f', ' %')} of those found labelled moving"


def _obstacles(m: Figures) -> str:
    return f"precision {num(m['precision'])}, {num(m['phantoms_per_frame'], '.2f')} phantoms per frame"


def _segmentation(m: Figures) -> str:
    return (
        f"one {num(m['one_cluster_pct'], '.1f', ' %')}  split {num(m['split_pct'], '.1f', ' %')}  "
        f"missed {num(m['missed_pct'], '.1f', ' %')}  merged {num(m['merged_pct'], '.1f', ' %')}  "
        f"phantoms {num(m['phantom_clusters_per_frame'], '.2f')} per frame"
    )


def _odometry(m: Figures) -> str:
    return (
        f"t_err {num(m['t_err_pct'], '.2f', ' %')}  r_err {num(m['r_err_deg_per_m'], '.4f', ' deg/m')}  "
        f"final drift {num(m['final_drift_pct'], '.2f', ' %')}"
    )


def _stereo(m: Figures) -> str:
    return (
        f"D1-all {num(m['d1_all_pct'], '.1f', ' %')}  D1-est {num(m['d1_est_pct'], '.1f', ' %')}  "
        f"density {num(m['density_pct'], '.1f', ' %')}"
    )


def _latency(m: Figures) -> str:
    return "  ".join(f"{stage} {num(v['p50'], '.1f')}/{num(v['p95'], '.1f')}" for stage, v in m.items())


ROWS: tuple[tuple[str, str, Callable[[Any], str]], ...] = (
    ("frames", "frames", str),
    ("moving", "moving obstacles", _moving),
    ("moving_tracks", "moving tracks", _moving_tracks),
    ("stationary_tracks", "stationary tracks", _stationary_tracks),
    ("id_switches", "id switches", str),
    ("speed", "speed error", _speed),
    ("stationary", "stationary obstacles", _stationary),
    ("obstacles", "all obstacles", _obstacles),
    ("segmentation", "voxel clusters", _segmentation),
    ("odometry", "odometry", _odometry),
    ("stereo", "stereo", _stereo),
    ("latency_ms", "latency ms p50/p95", _latency),
    ("throughput_hz", "throughput", lambda v: f"{v:.2f} Hz"),
)


def format_table(result: dict[str, Any], notes: list[str]) -> str:
    """One line per figure; a null one shows "-" and the notes below say why."""
    width = max(len(label) for _, label, _ in ROWS)
    lines = [f"{label:<{width}}  {'-' if result.get(key) is None else fmt(result[key])}" for key, label, fmt in ROWS]
    lines.extend(f"note: {note}" for note in notes)
    return "\n".join(lines)
