"""Where the stereo stage's time goes: per-step milliseconds over a recording's frames.

``python -m services.stereo_depth.benchmark RECORDING [--frames N] [--repeat R] [--set K=V]``
runs the core in this process (no bus, no serialisation) and prints, per step, the median, 95th
percentile and minimum of wall-clock milliseconds, plus the CPU milliseconds of the whole call
(both SGBM threads counted). On a shared machine other processes inflate wall time: the
minimum is the closest to an idle machine, and CPU time shows the work itself. A frame run again
is not newer than the last, so the followed corners start afresh each repeat (every corner found
anew): ``--repeat 1`` gives their cost in a stream.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Sequence

import numpy as np

from common.config_loading import load_config
from common.messages import StereoFrame
from common.recording import open_recording
from services.stereo_depth.core import StereoDepth
from services.stereo_depth.matcher import STEPS as MATCH_STEPS

STEPS: tuple[str, ...] = (*MATCH_STEPS, "reproject", "keypoints", "total")


def measure(core: StereoDepth, frames: Sequence[StereoFrame], repeat: int) -> dict[str, dict[str, float]]:
    """Per step p50/p95/min wall ms, and ``cpu`` ms; the first call (matcher construction) is left out."""
    core.process(frames[0])
    samples: dict[str, list[float]] = {step: [] for step in (*STEPS, "cpu")}
    for frame in frames:
        for _ in range(repeat):
            cpu_start = time.process_time()
            core.process(frame)
            samples["cpu"].append((time.process_time() - cpu_start) * 1000.0)
            for step, ms in core.step_timings_ms().items():
                samples[step].append(ms)
    return {
        step: {"p50": float(np.median(values)), "p95": float(np.percentile(values, 95)), "min": float(np.min(values))}
        for step, values in samples.items()
        if values
    }


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m services.stereo_depth.benchmark", description=__doc__)
    parser.add_argument("recording")
    parser.add_argument("--frames", type=int, default=10, help="first N stereo frames of the recording")
    parser.add_argument("--repeat", type=int, default=3, help="runs per frame")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="configuration override")
    args = parser.parse_args(argv)
    frames = list(open_recording(args.recording).by_topic("camera/stereo").values())[: args.frames]
    if not frames or not all(isinstance(f, StereoFrame) for f in frames):
        parser.error(f"{args.recording}: no camera/stereo frames")
    core = StereoDepth.from_config(load_config(sets=args.set))
    figures = measure(core, [f for f in frames if isinstance(f, StereoFrame)], args.repeat)
    height, width = frames[0].left.shape[:2]
    print(f"{width}x{height}, {len(frames)} frames x {args.repeat}, search range {core.search_range(frames[0].calib)}")
    for step, stats in figures.items():
        print(f"  {step:<12} p50 {stats['p50']:7.1f} ms   p95 {stats['p95']:7.1f} ms   min {stats['min']:7.1f} ms")
    print(json.dumps({"width": width, "height": height, "ms": figures}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
