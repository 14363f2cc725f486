"""Where a speed RMSE comes from: the true moving frames with the largest velocity errors.

    .venv/bin/python scripts/speed_errors.py /tmp/measure/urban-s*_run.mcap --top 10

Each run's clusters go through the tracker again (with ``--set`` over the run's configuration,
as ``scripts/sweep_tracker.py`` does), its obstacles are paired with the truth as ``evaluate``
pairs them, and every true-positive moving frame (those the speed RMSE is taken over) is listed
with its error split along the line of sight, across it and vertically, in the vehicle's frame.
It prints the pooled RMSE and its parts, the ``--top`` frames, and the RMSE without them: a few
frames often carry much of it (docs/results/tracking.md, "Session 56").
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "scripts"))

from sweep_tracker import load_run  # noqa: E402

from common.evaluation import metrics  # noqa: E402
from common.evaluation.evaluate import matched_frames  # noqa: E402
from services.pipeline import config_for  # noqa: E402
from services.tracker import Tracker  # noqa: E402


@dataclass(frozen=True)
class SpeedError:
    """One true moving frame's velocity error (m/s), in the vehicle's frame."""

    run: str
    frame: int
    truth: int
    obstacle: int
    range_m: float
    along: float  # along the line of sight to the obstacle (positive: away from the camera)
    across: float
    vertical: float
    true_speed: float

    @property
    def total(self) -> float:
        return float(np.sqrt(self.along**2 + self.across**2 + self.vertical**2))


def speed_errors(path: Path, sets: list[str]) -> list[SpeedError]:
    """The run's true-positive moving frames after warm-up and grace, as ``metrics.tally`` counts them."""
    run = load_run(path)
    tracker = Tracker.from_config(config_for(run.reader, None, sets, stored=True))
    run.inputs.obstacles = {f: tracker.process(clusters, ego) for f, clusters, ego in run.frames}
    frames = matched_frames(run.inputs)
    out = []
    for frame, young in list(zip(frames, metrics.grace_ids(frames), strict=True))[metrics.WARMUP_FRAMES :]:
        for d, det in enumerate(frame.detections):
            truth = frame.truth_of(d)
            if truth is None or not det.moving or metrics.scored_class(truth, young) != "moving":
                continue
            error = det.velocity - truth.velocity
            distance = max(float(np.hypot(det.centroid[0], det.centroid[1])), 1e-9)
            ux, uy = det.centroid[0] / distance, det.centroid[1] / distance
            out.append(SpeedError(
                run.name, frame.frame_id, truth.id, det.id, distance, float(error[0] * ux + error[1] * uy),
                float(error[1] * ux - error[0] * uy), float(error[2]), float(np.hypot(*truth.velocity[0:2])),
            ))  # fmt: skip
    return out


def rms(values: list[float]) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values else float("nan")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", type=Path, help="run recordings with ground truth (*_run.mcap)")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--top", type=int, default=10, help="frames to list, largest error first")
    args = parser.parse_args(argv)
    errors = sorted((e for path in args.runs for e in speed_errors(path, args.sets)), key=lambda e: -e.total)
    if not errors:
        print("speed_errors: no true moving frame in these runs", file=sys.stderr)
        return 1
    print(f"{len(errors)} true moving frames: RMSE {rms([e.total for e in errors]):.3f} m/s; along the line of "
          f"sight {rms([e.along for e in errors]):.3f}, across {rms([e.across for e in errors]):.3f}, "
          f"vertical {rms([e.vertical for e in errors]):.3f}")  # fmt: skip
    for e in errors[: args.top]:
        print(f"  {e.run} frame {e.frame:3d} truth {e.truth:4d} obstacle {e.obstacle:4d} at {e.range_m:5.1f} m: "
              f"{e.total:.2f} m/s (along {e.along:+.2f}, across {e.across:+.2f}, vertical {e.vertical:+.2f}; "
              f"true speed {e.true_speed:.2f})")  # fmt: skip
    rest = [e.total for e in errors[args.top :]]
    share = 1.0 - float(np.sum(np.square(rest))) / float(np.sum(np.square([e.total for e in errors])))
    print(f"these {min(args.top, len(errors))} carry {100 * share:.1f} % of the squared error; RMSE without them "
          f"{rms(rest):.3f} m/s")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
