"""Train the learned moving label (``tracker.motion_model``) on runs with ground truth, and export it as JSON.

    .venv/bin/python scripts/measure.py --out /tmp/tune --seeds 1,2,3,4,5,6,23,24,25,26,27,28 \\
        --only urban,crossing,overtake,slope
    .venv/bin/python scripts/train_motion_model.py --out services/tracker/motion_model.json \\
        --set tracker.motion_model= /tmp/tune/*_run.mcap

The bundled model was trained so in session 55, on those 48 runs: the tuning seeds 1-6 and the
six (23-28) the learned linkage was trained on; seeds 7-22 are the held-out, fresh and unseen
sets (docs/results/tracking.md, "Session 55"). Training is deterministic for a given list of runs
in a given order.

Each run's clusters go through the tracker again, with the configuration the run was made with
and ``--set`` over it. After every frame each tracked track becomes a row of
``motion_model.FEATURES``, and the evaluation's own matching (EVALUATION.md) says what it is on:
an object at 1 m/s or more is moving (1), one under 0.3 m/s stationary (0), and a track on no
object, a phantom or a second piece of one, is stationary too; tracks on objects in between, on
objects not counted, or left out by the evaluation (outside the volume, in a DontCare region) are
left out. The model is scikit-learn's ``HistGradientBoostingClassifier`` (the ``dev`` extra); the
file holds its trees' nodes (common/boosted_trees.py); nothing is pickled.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "scripts"))

from sweep_tracker import load_run  # noqa: E402
from tree_training import train  # noqa: E402

from common.evaluation.evaluate import matched_frames  # noqa: E402
from common.evaluation.matching import FrameMatch  # noqa: E402
from services.pipeline import config_for  # noqa: E402
from services.tracker import Tracker  # noqa: E402
from services.tracker.motion_model import FEATURES  # noqa: E402

F64 = npt.NDArray[np.float64]
#: a true object this fast (m/s) or faster is moving; slower than STILL_MPS, stationary (EVALUATION.md).
MOVING_MPS, STILL_MPS = 1.0, 0.3
#: the trees' settings (scikit-learn's names): 60 trees judged as 200 did on tracker replays and take a
#: third of the time to walk; with over 10,000 rows, early stopping may stop sooner, judged on a
#: tenth of them.
TREES: dict[str, Any] = {"max_iter": 60, "learning_rate": 0.15, "max_leaf_nodes": 15, "min_samples_leaf": 40,
                         "l2_regularization": 1.0, "random_state": 0}

#: more of these never lowers the chance of moving: the speeds and the lower bounds on it. Unbound,
#: trees trained on these runs gave a hand-built walker at 16 m, his 10 corners sure of 1.3 m/s,
#: 0.45-0.85 (tests/test_motion_model.py); bound, they judged the held-out runs as well.
RISING: tuple[str, ...] = ("filter_speed", "near_bound", "far_bound", "across_bound", "corner_speed", "corner_across")


def target(frame: FrameMatch, d: int) -> int | None:
    """1 if detection ``d`` is on a moving object, 0 on a standing one or on none, None if it is not scored."""
    det = frame.detections[d]
    truth = frame.truth_of(d)
    if truth is None:
        near = [frame.truths[j] for j in frame.near[d]] if frame.near else []
        if det.ignored or (near and all(not t.counted or t.motion == "between" for t in near)):
            return None
        return 0
    speed = float(np.hypot(truth.velocity[0], truth.velocity[1]))
    if not truth.counted or STILL_MPS <= speed < MOVING_MPS:
        return None
    return int(speed >= MOVING_MPS)


def run_rows(path: Path, sets: Sequence[str] = ()) -> tuple[F64, npt.NDArray[np.int64]]:
    """Every frame's scored rows of one run (tracked tracks only) and their answers."""
    run = load_run(path, "tracker")
    tracker = Tracker.from_config(config_for(run.reader, None, list(sets), stored=True))
    rows: dict[tuple[int, int], F64] = {}
    run.inputs.obstacles = {}
    for frame, clusters, ego in run.frames:
        run.inputs.obstacles[frame] = tracker.process(clusters, ego)
        eye = tracker._placement_pose(clusters, ego)[0:2, 3]
        features = tracker.labeller.features(tracker.tracks, clusters.voxel_edge, eye)
        for track_id, row in zip(tracker.tracks.ids.tolist(), features, strict=True):
            rows[(frame, track_id)] = row
    x: list[F64] = []
    y: list[int] = []
    for frame in matched_frames(run.inputs):
        for d, det in enumerate(frame.detections):
            answer = target(frame, d)
            if answer is not None and (frame.frame_id, det.id) in rows:
                x.append(rows[(frame.frame_id, det.id)])
                y.append(answer)
    if not x:
        return np.zeros((0, len(FEATURES))), np.zeros(0, dtype=np.int64)
    return np.array(x), np.array(y, dtype=np.int64)


def main(argv: list[str] | None = None) -> int:
    return train(argv, __doc__, "its clusters are tracked again", run_rows, FEATURES, TREES,
                 "{rows} tracked track-frames, {share:.1f} % on moving objects", RISING)


if __name__ == "__main__":
    raise SystemExit(main())
