"""How the clusters carve an overhanging obstacle: height span over the lane and free space beneath.

The issue's target for the synthetic ``hanging`` scenario: the overhanging obstacle's cluster
spans its true height within +-0.25 m and is not merged with the road below. The ground truth
box of a gantry or a cantilever sign reaches the road (its posts do), so the overhang itself is
rebuilt from the scenario's own parts (same scenario and seed as the recording): the parts that
do not stand on the ground are the overhang, their underside and top its true height (the top
clipped to the volume of interest). Per frame and per counted overhanging object, the clustered
voxels above the overhang's footprint over the carriageway (away from the posts, outside every
other true object) are collected; the cluster holding most of them is the overhang's cluster, and the span of its
voxel centres there, underside to top, is compared with the truth (a centre is the unbiased
place of what its cell holds, within half an edge; the cells' outer faces would add up to half
an edge on each side). Any clustered voxel centre there lower than the underside by more than
the tolerance means the free space beneath is not free: merged with (or cluttered by) what is
below. The cluster's whole box
(posts included) is reported beside it: it cannot reach below ``voxel.ground_clearance``.

``python -m services.voxel_mapper.overhang RUN.mcap`` prints the per-frame rows and a summary
(JSON with ``--json``).
"""

from __future__ import annotations

import argparse
import itertools
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from common.config import VolumeConfig
from common.evaluation.inputs import volume_of
from common.evaluation.matching import truth_in_vehicle
from common.evaluation.segmentation import inside_box
from common.geometry import invert
from common.messages import Clusters, GroundTruthEgo, GroundTruthObjects
from common.recording import open_recording
from common.scenarios.catalogue import build
from common.scenarios.road import Road

F64 = npt.NDArray[np.float64]
TOLERANCE_M = 0.25
POST_CLEARANCE_M = 0.5  # voxels this near a grounded part (a post) are the post's, not the overhang's


@dataclass(frozen=True)
class Overhang:
    """The overhanging parts of one object, in its frame (origin on the ground under its box centre)."""

    underside: float  # lowest overhanging part's bottom
    top: float  # the object's top, clipped to the volume of interest
    over: F64  # (n, 4): x_min, x_max, y_min, y_max of each overhanging part
    posts: F64  # (m, 4): the same for the parts standing on the ground


def _rects(parts: Sequence[Any]) -> F64:
    return np.array([(p.center[0] - p.size[0] / 2, p.center[0] + p.size[0] / 2,
                      p.center[1] - p.size[1] / 2, p.center[1] + p.size[1] / 2) for p in parts]).reshape(-1, 4)


def _inside(xy: F64, rects: F64, grow: float) -> npt.NDArray[np.bool_]:
    hit = np.zeros(len(xy), dtype=bool)
    for x0, x1, y0, y1 in rects:
        hit |= (xy[:, 0] >= x0 - grow) & (xy[:, 0] <= x1 + grow) & (xy[:, 1] >= y0 - grow) & (xy[:, 1] <= y1 + grow)
    return hit


def overhangs(scenario: str, seed: int, z_max: float) -> dict[int, Overhang]:
    """Objects of the scenario with parts above free space (a torso above legs is not one)."""
    out = {}
    for thing in build(scenario, seed).things:
        up = [p for p in thing.parts if p.center[2] - p.size[2] / 2 > 0.5]
        grounded = [p for p in thing.parts if p.center[2] - p.size[2] / 2 <= 0.5]
        if not up:
            continue
        over, posts = _rects(up), _rects(grounded)
        grid = np.mgrid[over[:, 0].min():over[:, 1].max():0.05, over[:, 2].min():over[:, 3].max():0.05].reshape(2, -1).T
        free = _inside(grid, over, 0.0) & ~_inside(grid, posts, POST_CLEARANCE_M)
        if np.count_nonzero(free) * 0.05**2 >= 0.25:
            top = min(thing.size[2], z_max)
            out[thing.id] = Overhang(min(p.center[2] - p.size[2] / 2 for p in up), top, over, posts)
    return out


def frame_rows(clusters: Clusters, truth: GroundTruthObjects, true_pose: F64, shapes: dict[int, Overhang],
               volume: VolumeConfig, road: Road | None = None) -> list[dict[str, Any]]:
    """One row per counted overhanging object: its cluster's span over the road and what lies beneath.

    With ``road`` only voxels over its carriageway count (true world frame = the scenario's).
    """
    to_vehicle = invert(np.asarray(clusters.ego_pose, dtype=np.float64))
    views = {obj.id: truth_in_vehicle(obj, true_pose, volume) for obj in truth.objects}
    rows = []
    for oid, view in views.items():
        shape = shapes.get(oid)
        if shape is None or not view.counted:
            continue
        others = [v for k, v in views.items() if k != oid]
        c, s = np.cos(view.yaw), np.sin(view.yaw)
        base = view.center - np.array([0.0, 0.0, view.size[2] / 2])
        best: tuple[int, Any, F64] | None = None
        below = 0
        for cluster in clusters.clusters:
            world = (np.asarray(cluster.voxels, dtype=np.float64) + 0.5) * clusters.voxel_edge
            vehicle = world @ to_vehicle[:3, :3].T + to_vehicle[:3, 3]
            mine = ~np.any([inside_box(vehicle, o, TOLERANCE_M) for o in others], axis=0) if others else True
            rel = vehicle - base
            local = np.stack([rel[:, 0] * c + rel[:, 1] * s, -rel[:, 0] * s + rel[:, 1] * c], axis=1)
            above = _inside(local, shape.over, TOLERANCE_M) & ~_inside(local, shape.posts, POST_CLEARANCE_M) & mine
            if road is not None:
                world = vehicle @ true_pose[:3, :3].T + true_pose[:3, 3]
                above &= np.abs(road.to_road(world[:, 0], world[:, 1])[1]) < road.half_width
            z = rel[above, 2]
            below += int(np.count_nonzero(z < shape.underside - TOLERANCE_M))
            if z.size and (best is None or z.size > best[0]):
                best = (z.size, cluster, z)
        row: dict[str, Any] = {"frame": truth.frame_id, "id": oid, "cls": truth_cls(truth, oid),
                               "range_m": float(view.center[0]), "true_underside": shape.underside,
                               "true_top": shape.top, "voxels_below": below}
        if best is None:
            row.update(underside=None, top=None, box_bottom=None, box_top=None, spans=False)
        else:
            underside, top = float(best[2].min()), float(best[2].max())
            corners = np.array(list(itertools.product(*zip(best[1].bbox_min, best[1].bbox_max, strict=True))))
            z_box = (corners @ to_vehicle[:3, :3].T + to_vehicle[:3, 3])[:, 2] - base[2]
            row.update(underside=underside, top=top, box_bottom=float(z_box.min()), box_top=float(z_box.max()),
                       spans=abs(underside - shape.underside) <= TOLERANCE_M and abs(top - shape.top) <= TOLERANCE_M)
        rows.append(row)
    return rows


def truth_cls(truth: GroundTruthObjects, oid: int) -> str:
    return next(o.cls for o in truth.objects if o.id == oid)


def measure(path: str | Path) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Per-frame rows and their summary for a run recording of a synthetic scenario."""
    rec = open_recording(path)
    info = rec.info()
    volume = volume_of(rec.config_dict(), info)
    shapes = overhangs(str(info["scenario"]), int(info["seed"]), volume.z_max)
    road = build(str(info["scenario"]), int(info["seed"])).road
    clusters: dict[int, Clusters] = {}
    truths: dict[int, GroundTruthObjects] = {}
    poses: dict[int, F64] = {}
    for _key, msg in rec.messages(topics=["voxel_mapper/clusters", "groundtruth/objects", "groundtruth/ego"]):
        if isinstance(msg, Clusters):
            clusters[msg.frame_id] = msg
        elif isinstance(msg, GroundTruthObjects):
            truths[msg.frame_id] = msg
        elif isinstance(msg, GroundTruthEgo):
            poses[msg.frame_id] = np.asarray(msg.pose, dtype=np.float64)
    rows = []
    for fid in sorted(set(clusters) & set(truths) & set(poses)):
        rows += frame_rows(clusters[fid], truths[fid], poses[fid], shapes, volume, road)
    seen = [r for r in rows if r["underside"] is not None]

    def share(flags: list[bool]) -> float | None:
        return 100.0 * sum(flags) / len(rows) if rows else None

    def median(values: list[float]) -> float | None:
        return float(np.median(values)) if values else None

    summary = {
        "rows": len(rows),
        "found_pct": share([r["underside"] is not None for r in rows]),
        "spans_pct": share([r["spans"] for r in rows]),
        "free_below_pct": share([r["voxels_below"] == 0 for r in rows]),
        "underside_err_median_m": median([r["underside"] - r["true_underside"] for r in seen]),
        "top_err_median_m": median([r["top"] - r["true_top"] for r in seen]),
        "box_bottom_median_m": median([r["box_bottom"] for r in seen]),
    }
    return rows, summary


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", help="run recording (stereovox process) of a synthetic scenario")
    parser.add_argument("--json", action="store_true", help="print the summary only, as JSON")
    args = parser.parse_args(argv)
    rows, summary = measure(args.recording)
    if not args.json:
        for r in rows:
            span = "-" if r["underside"] is None else f"{r['underside']:.2f}..{r['top']:.2f}"
            span += "" if r["underside"] is None else f" (box from {r['box_bottom']:.2f})"
            print(f"frame {r['frame']:3d} {r['cls']:8s} x {r['range_m']:5.1f} m  over the lane {span:26s} "
                  f"true {r['true_underside']:.2f}..{r['true_top']:.2f}  voxels below {r['voxels_below']}")
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
