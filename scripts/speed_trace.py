"""One object's true speed against what runs reported for it, frame by frame, as a picture.

``python scripts/speed_trace.py RUN [RUN ...] --truth ID --out PNG [--names A,B]`` reads each run
recording (``stereovox process`` output, or a replay of it), matches its obstacles to the truth as
``stereovox evaluate`` does, and plots the truth's speed and, per run, the speed of the obstacle
matched to it, filled where that obstacle is labelled moving. Comparing a run with a replay of it
under another setting shows what the setting did to one object (docs/results/tracking.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from common.evaluation.evaluate import matched_frames
from common.evaluation.inputs import read_inputs

Trace = tuple[list[int], list[float], list[float], list[bool]]


def trace(run: Path, truth_id: int) -> Trace:
    """Frames, true speed, matched obstacle's speed (NaN: none) and its moving label."""
    frames, true, seen, moving = [], [], [], []
    for frame in matched_frames(read_inputs(run)):
        det_of = frame.detection_of()
        for t, truth in enumerate(frame.truths):
            if truth.id != truth_id:
                continue
            d = det_of.get(t)
            frames.append(frame.frame_id)
            true.append(float(np.hypot(*truth.velocity[:2])))
            seen.append(float(np.hypot(*frame.detections[d].velocity[:2])) if d is not None else float("nan"))
            moving.append(d is not None and bool(frame.detections[d].moving))
    return frames, true, seen, moving


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--truth", type=int, required=True, help="ground-truth object id")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--names", help="comma-separated, one per run (default: file names)")
    args = parser.parse_args()
    names = args.names.split(",") if args.names else [r.stem for r in args.runs]
    fig, ax = plt.subplots(figsize=(8, 3.6))
    for k, (run, name) in enumerate(zip(args.runs, names, strict=True)):
        frames, true, seen, moving = trace(run, args.truth)
        if not frames:
            parser.error(f"{run}: no truth object {args.truth}")
        if k == 0:
            ax.plot(frames, true, "k-", lw=2, label="truth")
        line = ax.plot(frames, seen, "o-", ms=4, lw=1, label=f"{name}: reported (filled: labelled moving)")[0]
        for f, s, m in zip(frames, seen, moving, strict=True):
            if m:
                ax.plot(f, s, "o", ms=7, color=line.get_color())
    ax.set_xlabel("frame")
    ax.set_ylabel("speed (m/s)")
    ax.set_title(f"truth object {args.truth}")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
