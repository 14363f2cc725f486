"""How well the voxel clusters (before tracking) carve the scene into objects.

Scored separately from the tracker so that a segmentation fault (a car split in two, two
pedestrians merged) is visible even when the tracker hides or amplifies it.
"""

from __future__ import annotations

import itertools

import numpy as np
import numpy.typing as npt

from common.evaluation.inputs import FrameClusters
from common.evaluation.matching import TruthView, inside_box_xy
from common.evaluation.metrics import share
from common.geometry import invert

F64 = npt.NDArray[np.float64]

#: cluster centroid inside the object's box grown by this much (m) to belong to it.
CLUSTER_MARGIN_M: float = 0.25


def clusters_in_vehicle(frame: FrameClusters) -> tuple[F64, F64, F64]:
    """Centroids (N x 3) and axis-aligned boxes (min, max) of the clusters in the vehicle frame."""
    if not frame.boxes:
        empty = np.zeros((0, 3))
        return empty, empty, empty
    to_vehicle = invert(frame.ego_pose)
    rot, trans = to_vehicle[:3, :3], to_vehicle[:3, 3]
    centroids = np.array([b.centroid for b in frame.boxes]) @ rot.T + trans
    lows, highs = [], []
    for b in frame.boxes:
        corners = np.array(list(itertools.product(*zip(b.bbox_min, b.bbox_max, strict=True)))) @ rot.T + trans
        lows.append(corners.min(axis=0))
        highs.append(corners.max(axis=0))
    return centroids, np.array(lows), np.array(highs)


def inside_box(points: F64, truth: TruthView, margin: float) -> npt.NDArray[np.bool_]:
    """Which points fall inside the object's oriented 3-D box grown by ``margin``."""
    if len(points) == 0:
        return np.zeros(0, dtype=bool)
    in_xy = inside_box_xy(points[:, :2], truth.center, truth.size, truth.yaw, margin)
    in_z = np.abs(points[:, 2] - truth.center[2]) <= truth.size[2] / 2 + margin
    return in_xy & in_z


def clusters_on(centroids: F64, truth: TruthView) -> int:
    """How many clusters belong to the object: their centroids inside its box grown by ``CLUSTER_MARGIN_M``."""
    return int(inside_box(centroids, truth, CLUSTER_MARGIN_M).sum())


def _corners_xy(truth: TruthView) -> F64:
    c, s = np.cos(truth.yaw), np.sin(truth.yaw)
    half = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * truth.size[:2] / 2
    return truth.center[:2] + half @ np.array([[c, s], [-s, c]])


def box_overlaps(low: F64, high: F64, truth: TruthView) -> bool:
    """Whether an axis-aligned box and the object's (ungrown) oriented box share any volume.

    Separating-axis test from above (the box's two axes and the object's two), then heights.
    """
    if high[2] <= truth.center[2] - truth.size[2] / 2 or low[2] >= truth.center[2] + truth.size[2] / 2:
        return False
    aabb = np.array([[low[0], low[1]], [low[0], high[1]], [high[0], high[1]], [high[0], low[1]]])
    return _footprints_meet(_corners_xy(truth), aabb, (0.0, truth.yaw))


def truths_share_volume(a: TruthView, b: TruthView) -> bool:
    """Whether two objects' oriented boxes share any volume: the scene has put one inside the other.

    No real pair can, so a truth-frame that does is one neither stereo nor any clustering could
    tell apart (a bin standing inside a kiosk, a cyclist riding through a pole).
    """
    if abs(a.center[2] - b.center[2]) >= (a.size[2] + b.size[2]) / 2:
        return False
    return _footprints_meet(_corners_xy(a), _corners_xy(b), (a.yaw, b.yaw))


def _footprints_meet(a: F64, b: F64, yaws: tuple[float, float]) -> bool:
    """Separating-axis test of two rectangles seen from above, whose sides lie along ``yaws``."""
    for yaw in yaws:
        c, s = np.cos(yaw), np.sin(yaw)
        for axis in (np.array([c, s]), np.array([-s, c])):
            pa, pb = a @ axis, b @ axis
            if pa.max() <= pb.min() or pb.max() <= pa.min():
                return False
    return True


def phantom_count(centroids: F64, lows: F64, highs: F64, truths: list[TruthView]) -> int:
    """Clusters on no true object at all: centroid in no grown box and box touching none.

    Every object counts here, ignored ones too: with complete truth, anything that is not a
    listed structure is something the mapper invented.
    """
    phantoms = 0
    for centroid, low, high in zip(centroids, lows, highs, strict=True):
        claimed = any(
            inside_box(centroid[None, :], t, CLUSTER_MARGIN_M)[0] or box_overlaps(low, high, t) for t in truths
        )
        phantoms += not claimed
    return phantoms


def segmentation_figures(
    frames: list[tuple[list[TruthView], FrameClusters]], gt_complete: bool
) -> dict[str, float | None] | None:
    """One/split/missed shares of counted objects, merged share of clusters on objects, phantoms."""
    objects = one = split = missed = 0
    on_objects = merged = phantoms = 0
    for truths, clusters in frames:
        centroids, lows, highs = clusters_in_vehicle(clusters)
        counted = [t for t in truths if t.counted]
        for truth in counted:
            n = clusters_on(centroids, truth)
            objects += 1
            one += n == 1
            split += n > 1
            missed += n == 0
        for low, high in zip(lows, highs, strict=True):
            touched = sum(box_overlaps(low, high, t) for t in counted)
            on_objects += touched >= 1
            merged += touched >= 2
        if gt_complete:
            phantoms += phantom_count(centroids, lows, highs, truths)
    if not frames:
        return None
    return {
        "one_cluster_pct": share(one, objects, 100.0),
        "split_pct": share(split, objects, 100.0),
        "missed_pct": share(missed, objects, 100.0),
        "merged_pct": share(merged, on_objects, 100.0),
        "phantom_clusters_per_frame": share(phantoms, len(frames)) if gt_complete else None,
    }
