"""Train the learned linkage (``voxel.join_model``) on runs with ground truth, and export it as JSON.

    .venv/bin/python scripts/measure.py --out /tmp/tune --seeds 1,2,3,4,5,6,23,24,25,26,27,28 \\
        --only urban,crossing,overtake,slope
    .venv/bin/python scripts/train_join_model.py --out services/voxel_mapper/join_model.json /tmp/tune/*_run.mcap

The bundled model was trained so in session 53, on those 48 runs: the tuning seeds 1-6 and six
more (23-28) that no evaluation uses; seeds 7-22 are the held-out, fresh and unseen sets
(docs/results/voxel.md, "Session 53"). Training is deterministic for a given list of runs in a
given order.

Each run's clouds go through the voxel mapper again. At every frame the flood fill's parts that
the linkage links (both ways, through neighbours, bridges and steps, both at least
``voxel.join_min_voxels``) become rows of ``part_pairs.FEATURES``. Each voxel belongs to the true
object whose box is nearest it, within ``OWNER_REACH_M`` (a walker's smear goes with the walker), and
a part to the object most of its voxels belong to; a pair is one object when both parts belong to
the same one, two when they belong to different ones, and is left out when either belongs to
none. The model is scikit-learn's ``HistGradientBoostingClassifier`` (the ``dev`` extra), with
both answers weighed alike: three in four linked pairs are one object, and the rarer mistake, two
objects joined, is the one that loses walkers. The file holds the trees' nodes, walked by
``services/voxel_mapper/join_model.py``; nothing is pickled.
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

from common.boosted_trees import export as export_trees  # noqa: E402
from services.pipeline import config_for  # noqa: E402
from services.voxel_mapper import VoxelMapper  # noqa: E402
from services.voxel_mapper.core import PartsSeen  # noqa: E402
from services.voxel_mapper.linkage import part_links  # noqa: E402
from services.voxel_mapper.part_pairs import FEATURES, pair_features  # noqa: E402

F64 = npt.NDArray[np.float64]
#: a voxel this near an object's box (m) is that object's: smear beside a walker is the walker's.
OWNER_REACH_M: float = 1.5
#: the trees' settings (scikit-learn's names); early stopping picks how many, on a tenth of the rows.
TREES: dict[str, Any] = {"max_iter": 200, "max_depth": 6, "class_weight": "balanced", "random_state": 0}

Box = tuple[F64, F64, float]  # centre (world), size (length, width, height), yaw


def owners(points: F64, boxes: list[Box]) -> npt.NDArray[np.int64]:
    """Index of the box each point is nearest (distance outside it, 0 inside), within the reach; -1 for none.

    Where boxes nest (a bin inside a kiosk's box), the smaller one wins: a tiny share of its size
    is added to every distance.
    """
    owner = np.full(len(points), -1, dtype=np.int64)
    best = np.full(len(points), np.inf)
    for i, (centre, size, yaw) in enumerate(boxes):
        d = points - centre
        c, s = np.cos(yaw), np.sin(yaw)
        outside = np.column_stack([
            np.abs(d[:, 0] * c + d[:, 1] * s) - size[0] / 2,
            np.abs(-d[:, 0] * s + d[:, 1] * c) - size[1] / 2,
            np.abs(d[:, 2]) - size[2] / 2,
        ])  # fmt: skip
        dist = np.linalg.norm(np.maximum(outside, 0.0), axis=1) + 1e-3 * float(np.prod(size)) ** (1 / 3)
        take = (dist < OWNER_REACH_M) & (dist < best)
        owner[take], best[take] = i, dist[take]
    return owner


def part_owners(points: F64, parts: npt.NDArray[np.int32], n_parts: int, boxes: list[Box]) -> npt.NDArray[np.int64]:
    """Each part's object: the one most of its points are nearest (:func:`owners`); -1 where none is near."""
    votes = np.zeros((n_parts, len(boxes) + 1), dtype=np.int64)
    np.add.at(votes, (parts, owners(points, boxes) + 1), 1)
    votes[:, 0] = 0  # points near no object do not vote
    return np.where(votes.max(axis=1) > 0, votes.argmax(axis=1) - 1, -1)


def labelled_pairs(seen: PartsSeen, boxes: list[Box]) -> tuple[F64, npt.NDArray[np.bool_]]:
    """This frame's rows of linked big parts that both lie on an object, and whether it is the same one."""
    members = np.flatnonzero(seen.labels >= 0)
    empty = (np.zeros((0, len(FEATURES))), np.zeros(0, dtype=bool))
    if members.size == 0:
        return empty
    direct, stepped = part_links(seen.vmap, seen.labels, members, seen.n_parts, seen.position,
                                 seen.bridge_voxels, seen.step_voxels)
    a, b, rows = pair_features(seen.vmap, seen.labels, members, seen.n_parts, seen.position, seen.height,
                               direct, stepped)
    lab = seen.labels[members]
    part_owner = part_owners(seen.vmap.centroids[members], lab, seen.n_parts, boxes)
    sizes = np.bincount(lab, minlength=seen.n_parts)
    keep = (sizes[a] >= seen.min_voxels) & (sizes[b] >= seen.min_voxels)
    keep &= (part_owner[a] >= 0) & (part_owner[b] >= 0)
    return rows[keep], (part_owner[a] == part_owner[b])[keep]


def run_rows(path: Path, sets: Sequence[str] = ()) -> tuple[F64, npt.NDArray[np.bool_]]:
    """Every frame's labelled rows of one run, its clouds mapped again with the configuration it was made
    with and ``sets`` (``key=value``) over it."""
    run = load_run(path, "voxel_mapper")
    mapper = VoxelMapper.from_config(config_for(run.reader, None, [*sets, "voxel.join_model="], stored=True))
    rows: list[F64] = []
    same: list[npt.NDArray[np.bool_]] = []
    boxes: list[Box] = []

    def collect(seen: PartsSeen) -> None:
        x, y = labelled_pairs(seen, boxes)
        rows.append(x)
        same.append(y)

    mapper.parts_seen = collect
    for frame, cloud, ego in run.frames:
        true_pose = run.inputs.true_poses.get(frame)
        truth = run.inputs.truth.get(frame)
        if true_pose is None or truth is None:
            continue
        to_estimate = np.asarray(ego.pose) @ np.linalg.inv(true_pose)  # truth into the mapper's world
        turn = float(np.arctan2(to_estimate[1, 0], to_estimate[0, 0]))
        boxes[:] = [(to_estimate[:3, :3] @ np.asarray(o.center) + to_estimate[:3, 3], np.asarray(o.size),
                     float(o.yaw) + turn) for o in truth.objects]
        mapper.process(cloud, ego)
    if not rows:
        return np.zeros((0, len(FEATURES))), np.zeros(0, dtype=bool)
    return np.concatenate(rows), np.concatenate(same)


def export(model: Any) -> dict[str, Any]:
    """A fitted HistGradientBoostingClassifier's trees as flat node arrays (join_model.JoinModel's file)."""
    return export_trees(model, FEATURES)


def main(argv: list[str] | None = None) -> int:
    return train(argv, __doc__, "its parts are mapped again", run_rows, FEATURES, TREES,
                 "{rows} linked pairs, {share:.1f} % one object")


if __name__ == "__main__":
    raise SystemExit(main())
