"""How far the obstacle figures could go with the mapper's own voxels cut into objects by the truth.

    .venv/bin/python scripts/segmentation_ceiling.py --mode truth /tmp/measure/urban-s*_run.mcap \\
        [--set voxel.join_model=]

Each run's clouds go through the mapper and the tracker again, with one of its steps handed to
the ground truth, and are scored as ``evaluate`` scores them (in the paper's volume, as
``scripts/measure.py``'s tables are):

- ``truth``: every clustered voxel inside an object's box grown by ``GROWN_M`` becomes that
  object's cluster, and every other voxel is dropped: segmentation made perfect, smear and all.
- ``nearest``: every clustered voxel within ``train_join_model.OWNER_REACH_M`` of an object's box
  goes to the nearest one, the rest keep their clusters: objects cut apart, each with its smear.
- ``joins``: the flood fill's parts as they are, joined when most of their voxels lie nearest one
  object (instead of ``voxel.join_share`` and the apart rule), touching or not.
- ``linked``: the same, but only pairs of parts the mapper links (neighbours, bridges and steps, as
  ``linkage.part_links`` finds them) of at least ``--min-voxels`` each; with ``--reach R`` (2 or
  more) also pairs with voxels up to R voxels apart along each axis: the ceiling of a linkage that
  judges those pairs.

Session 53's figures (docs/results/voxel.md) came from here, and session 59's.
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "scripts"))

from sweep_tracker import load_run, scenario  # noqa: E402
from train_join_model import Box, owners, part_owners  # noqa: E402

from common.config import VolumeConfig  # noqa: E402
from common.evaluation.evaluate import Evaluation, obstacle_figures  # noqa: E402
from common.evaluation.inputs import cluster_boxes  # noqa: E402
from common.evaluation.matching import inside_box_xy  # noqa: E402
from services.pipeline import config_for  # noqa: E402
from services.tracker import Tracker  # noqa: E402
from services.voxel_mapper import VoxelMapper  # noqa: E402
from services.voxel_mapper import core as mapper_core  # noqa: E402
from services.voxel_mapper.flood_fill import neighbour_deltas, touching_pairs  # noqa: E402
from services.voxel_mapper.linkage import part_links  # noqa: E402

#: ``truth``: a voxel inside an object's box grown by this much (m) is the object's.
GROWN_M: float = 0.15
I32 = npt.NDArray[np.int32]


def inside(points: npt.NDArray[np.float64], boxes: list[Box]) -> npt.NDArray[np.int64]:
    """The smallest grown box holding each point, or -1."""
    owner = np.full(len(points), -1, dtype=np.int64)
    best = np.full(len(points), np.inf)
    for i, (centre, size, yaw) in enumerate(boxes):
        held = inside_box_xy(points[:, :2], centre, size, yaw, GROWN_M)
        held &= np.abs(points[:, 2] - centre[2]) <= size[2] / 2 + GROWN_M
        take = held & (float(np.prod(size)) < best)
        owner[take], best[take] = i, float(np.prod(size))
    return owner


class Oracle:
    """The truth's boxes for the frame being mapped, and the mapper step it replaces."""

    def __init__(self, mode: str, min_voxels: int = 1, reach: int = 0) -> None:
        self.mode = mode
        self.min_voxels = min_voxels
        self.reach = reach
        self.boxes: list[Box] = []
        self._describe = mapper_core.describe
        self._join = mapper_core.join_parts

    def install(self) -> None:
        if self.mode in ("joins", "linked"):
            mapper_core.join_parts = self.join
        else:
            mapper_core.describe = self.describe

    def describe(self, vmap: Any, labels: I32, height: Any) -> Any:
        clustered = labels >= 0
        points = vmap.centroids[: len(labels)]
        if self.mode == "truth":
            own = inside(points, self.boxes)
            labels = np.where(clustered & (own >= 0), own, -1).astype(np.int32)
        else:
            own = owners(points, self.boxes)
            first = int(labels.max()) + 1 if len(labels) else 0
            labels = np.where(clustered & (own >= 0), first + own, labels).astype(np.int32)
        return self._describe(vmap, labels, height)

    def join(self, vmap: Any, labels: I32, n_clusters: int, position: Any, _min: int, _share: float,
             bridge_voxels: int, step_voxels: int = 0, *_: Any, **__: Any) -> I32:
        members = np.flatnonzero(labels >= 0)
        whose = part_owners(vmap.centroids[members], labels[members], n_clusters, self.boxes)
        if self.mode == "linked":
            root = self._linked_roots(vmap, labels, members, n_clusters, position, bridge_voxels, step_voxels, whose)
        else:
            first = np.full(len(self.boxes) + 1, -1)
            root = np.arange(n_clusters)
            for part in range(n_clusters):
                if whose[part] >= 0:
                    if first[whose[part]] < 0:
                        first[whose[part]] = part
                    root[part] = first[whose[part]]
        out = labels.copy()
        out[members] = root[labels[members]]
        return out

    def _linked_roots(self, vmap: Any, labels: I32, members: npt.NDArray[np.int64], n_clusters: int, position: Any,
                      bridge_voxels: int, step_voxels: int, whose: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
        """Each part's label once the pairs the truth calls one object are joined (groups relabelled as they meet)."""
        direct, stepped = part_links(vmap, labels, members, n_clusters, position, bridge_voxels, step_voxels)
        packed = np.concatenate([direct[0], stepped[0]])
        a, b = packed // n_clusters, packed % n_clusters
        if self.reach >= 2:
            near = touching_pairs(vmap, labels, neighbour_deltas(self.reach))
            a, b = np.concatenate([a, near[:, 0]]), np.concatenate([b, near[:, 1]])
        sizes = np.bincount(labels[members], minlength=n_clusters)
        one = (sizes[a] >= self.min_voxels) & (sizes[b] >= self.min_voxels) & (whose[a] >= 0) & (whose[a] == whose[b])
        root = np.arange(n_clusters)
        for x, y in zip(a[one], b[one], strict=True):  # relabel y's group to x's, smallest label first
            rx, ry = root[x], root[y]
            if rx != ry:
                root[root == max(rx, ry)] = min(rx, ry)
        return root


def run_figures(path: Path, oracle: Oracle, sets: list[str]) -> dict[str, Any]:
    run = load_run(path, "voxel_mapper")
    if not run.name.startswith("kitti"):
        run.inputs.volume = VolumeConfig()  # the paper's volume, as measure.py scores
    cfg = config_for(run.reader, None, sets, stored=True)
    mapper, tracker = VoxelMapper.from_config(cfg), Tracker.from_config(cfg)
    run.inputs.obstacles = {}
    for frame, cloud, ego in run.frames:
        to_estimate = np.asarray(ego.pose) @ np.linalg.inv(run.inputs.true_poses[frame])
        turn = float(np.arctan2(to_estimate[1, 0], to_estimate[0, 0]))
        oracle.boxes = [(to_estimate[:3, :3] @ np.asarray(o.center) + to_estimate[:3, 3], np.asarray(o.size),
                         float(o.yaw) + turn) for o in run.inputs.truth[frame].objects]
        clusters = mapper.process(cloud, ego)
        run.inputs.clusters[frame] = cluster_boxes(clusters)
        run.inputs.obstacles[frame] = tracker.process(clusters, ego)
    figures = obstacle_figures(run.inputs, Evaluation(result={}))
    moving, speed = figures["moving"] or {}, figures["speed"] or {}
    return {"name": run.name, "tp": moving.get("tp", 0), "fp": moving.get("fp", 0), "fn": moving.get("fn", 0),
            "pairs": speed.get("pairs", 0), "rmse": speed.get("rmse_mps") or 0.0,
            "one": (figures["segmentation"] or {}).get("one_cluster_pct")}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", type=Path, help="run recordings with ground truth (*_run.mcap)")
    parser.add_argument("--mode", choices=("truth", "nearest", "joins", "linked"), required=True)
    parser.add_argument("--min-voxels", type=int, default=1, help="linked: the smallest parts joined")
    parser.add_argument("--reach", type=int, default=0, help="linked: also parts this many voxels apart (2 or more)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="configuration over the run's own (session 53: voxel.join_model= for the share rule)")
    args = parser.parse_args(argv)
    oracle = Oracle(args.mode, args.min_voxels, args.reach)
    oracle.install()
    pooled: dict[str, list[Any]] = defaultdict(list)
    for path in args.runs:
        row = run_figures(path, oracle, args.set)
        pooled[scenario(row["name"])].append(row)
        print(f"{row['name']}: moving TP / FP / FN {row['tp']} / {row['fp']} / {row['fn']}, "
              f"speed RMSE {row['rmse']:.2f} m/s, one cluster {row['one'] or 0:.1f} %", flush=True)
    for name, rows in sorted(pooled.items()):
        tp, fp, fn = (sum(r[k] for r in rows) for k in ("tp", "fp", "fn"))
        pairs = sum(r["pairs"] for r in rows)
        rmse = np.sqrt(sum(r["pairs"] * r["rmse"] ** 2 for r in rows) / max(pairs, 1))
        one = np.mean([r["one"] for r in rows if r["one"] is not None] or [0.0])
        print(f"{name} ({args.mode}): {tp} / {fp} / {fn}, TP {100 * tp / max(tp + fp + fn, 1):.1f} %, "
              f"RMSE {rmse:.2f} m/s, one cluster {one:.1f} %")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
