"""``--plots DIR``: the pictures that explain an evaluation's numbers at a glance.

Trajectories show where odometry drift comes from, the speed-error histogram whether the RMSE is
a few outliers or a bias, and per-stage latency over time whether a slow stage is slow always or
only in bursts (contention, a garbage collection, a scene with many clusters). The moving
outcomes (``evaluate --why`` as bars) show which kind of object is missed, and whether the tracker
lost it (a wrong label) or the voxel mapper did (no track, the object inside a neighbour's cluster).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from common.errors import InputError

if TYPE_CHECKING:
    from common.evaluation.breakdown import Breakdown
    from common.evaluation.evaluate import Evaluation


def _pyplot():  # type: ignore[no-untyped-def]
    """matplotlib with a file-only backend, imported only when plots are asked for."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _trajectory(ev: Evaluation, path: Path) -> Path | None:
    if not ev.true_trajectory:
        return None
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 6))
    true_xy = np.array([p[:2, 3] for p in ev.true_trajectory])
    est_xy = np.array([p[:2, 3] for p in ev.est_trajectory])
    ax.plot(true_xy[:, 1], true_xy[:, 0], "k-", label="true")
    ax.plot(est_xy[:, 1], est_xy[:, 0], "r--", label="estimated")
    ax.set_xlabel("y (m, left positive)")
    ax.set_ylabel("x (m, forward)")
    ax.invert_xaxis()
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend()
    ax.set_title("vehicle trajectory, frame 0 at the origin")
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path


def _speed_histogram(ev: Evaluation, path: Path) -> Path | None:
    errors = ev.tally.speed_errors
    if not errors:
        return None
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.hist(errors, bins=min(40, max(5, len(errors) // 5)), color="steelblue")
    ax.set_xlabel("speed error |v_est - v_true| (m/s)")
    ax.set_ylabel("true-positive pairs")
    ax.set_title("speed error of moving obstacles")
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path


def _latency(ev: Evaluation, path: Path) -> Path | None:
    if not ev.stage_ms:
        return None
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 4))
    for stage, per_frame in ev.stage_ms.items():
        frames = sorted(per_frame)
        ax.plot(frames, [per_frame[f] for f in frames], label=stage, linewidth=1)
    ax.set_xlabel("frame id")
    ax.set_ylabel("stage time (ms)")
    ax.set_title("per-stage latency")
    ax.legend(fontsize="small")
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path


def _moving_outcomes(why: Breakdown, path: Path) -> Path | None:
    from common.evaluation.breakdown import FOUND, NO_TRACK, WRONG_LABEL

    if not why.moving:
        return None
    plt = _pyplot()
    classes = sorted({cls for cls, _, _ in why.moving})
    parts = (  # (label, colour, which rows)
        ("found", "#4c9a2a", lambda o, s: o == FOUND),
        ("tracked, labelled stationary", "#e39b2d", lambda o, s: o == WRONG_LABEL),
        ("no track, a cluster of its own", "#8064a2", lambda o, s: o == NO_TRACK and s in ("one", "split")),
        ("no track, inside a neighbour's cluster", "#c0504d", lambda o, s: o == NO_TRACK and s == "merged"),
        ("no track, no cluster", "#9a9a9a", lambda o, s: o == NO_TRACK and s in ("none", "no clusters")),
    )
    fig, ax = plt.subplots(figsize=(7, 0.6 * len(classes) + 1.6))
    left = np.zeros(len(classes))
    for label, colour, takes in parts:
        counts = np.zeros(len(classes))
        for (cls, outcome, segment), n in why.moving.items():
            if takes(outcome, segment):
                counts[classes.index(cls)] += n
        ax.barh(classes, counts, left=left, color=colour, label=label)
        left += counts
    ax.set_xlabel("moving truth-frames scored")
    ax.set_title("what became of the moving objects, per class")
    ax.invert_yaxis()
    ax.legend(fontsize="small", loc="upper center", bbox_to_anchor=(0.5, -0.18), ncol=2)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path


def write_plots(ev: Evaluation, out_dir: Path, why: Breakdown | None = None) -> list[Path]:
    """Write whichever plots the recording has data for; returns the files written.

    ``why`` (breakdown.py) adds the moving objects' outcomes per class.
    """
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create plot folder {out_dir}: {exc.strerror}") from None
    written = [
        _trajectory(ev, out_dir / "trajectory.png"),
        _speed_histogram(ev, out_dir / "speed_error.png"),
        _latency(ev, out_dir / "latency.png"),
        None if why is None else _moving_outcomes(why, out_dir / "moving_outcomes.png"),
    ]
    return [p for p in written if p is not None]
