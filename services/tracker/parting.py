"""A cluster that holds two known objects, parted between them before association (an option, off).

Stereo smear strings a walker to the bin, pole or facade behind him along the line of sight, and
parked cars to each other and to the hedge behind them; the flood fill then gives them one
cluster (synthetic urban, held-out seeds 7-10: 77 of the 113 walker-frames with no cluster centred
on them lie in a cluster shared with another object). Association gives that cluster to one track; its
centroid lies between the objects, so the track that takes it slides onto neither and the others
go unseen. When the tracker already knows the objects, their boxes say which voxels are whose:
every voxel goes to the nearest claimant's box, and each track is offered its own part.

What claims, and what is believed of a part, was measured step by step on tracker replays
(docs/results/tracking.md, "Session 37"):

- a claimant is a confirmed track (tracked, or a ghost lost for a frame or two) at least
  ``min_age`` frames old, whose box is an object's (``max_extent_m``), not a row of cars and
  hedge; where two claimants' centres lie in each other's boxes they are one object seen twice,
  and the older claims alone; a part too small to be an object withdraws its claimant;
- a claimant's box is where it was last seen, not where its filter expects it: a track sliding
  along a hedge would claim the voxels ahead of it and measure its own slide;
- a cluster the image's side edge cuts is not parted: the parts' ends there move with the car;
- only tracks labelled stationary claim (``standing_only``): walkers' parts cost moving frames;
- a part's centroid is doubted by a share of its extent (``doubt``), a part may keep a moving
  label but never give one, and a track's speed window restarts after a part: where a part ends
  is the parting's guess, not the object's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from common.messages import Cluster
from services.tracker.anchor import anchors
from services.tracker.track import GHOST, TRACKED, TrackTable

NDArray = npt.NDArray[Any]


@dataclass(frozen=True)
class Parting:
    """When a shared cluster is parted (config: ``tracker.part_*``)."""

    min_voxels: int = 0  # fewest voxels a part keeps; 0: off
    min_age: int = 0  # frames of track a claimant needs
    doubt: float = 0.0  # a part's centroid std is this share of its extent, per axis, on top of the cluster's
    keep_cut: bool = False  # a cluster the image's side edge cuts is never parted
    max_extent_m: float = float("inf")  # a claimant's box is no longer than this, in x and y: an object's, not a row's
    standing_only: bool = False  # only tracks labelled stationary claim


#: clusters are never parted.
NO_PARTING = Parting()


def _distance_to_boxes(points: NDArray, lo: NDArray, hi: NDArray) -> NDArray:
    """(points x boxes) Euclidean distance from each point to each box, 0 inside."""
    below = np.maximum(lo[None, :, :] - points[:, None, :], 0.0)
    above = np.maximum(points[:, None, :] - hi[None, :, :], 0.0)
    return np.linalg.norm(below + above, axis=2)


def _inside(points: NDArray, lo: NDArray, hi: NDArray) -> NDArray:
    """(points x boxes) True where the point lies in the box, seen from above."""
    p = points[:, None, 0:2]
    return np.all((p >= lo[None, :, 0:2]) & (p <= hi[None, :, 0:2]), axis=2)


def distinct(centre: NDArray, lo: NDArray, hi: NDArray, rank: NDArray) -> NDArray:
    """Indices of claimants that are objects apart, the higher ``rank`` first kept.

    A claimant is kept when its centre is in no kept claimant's box and no kept claimant's
    centre is in its box.
    """
    inside = _inside(centre, lo, hi)  # [i, j]: i's centre in j's box
    kept: list[int] = []
    for i in np.argsort(-rank, kind="stable").tolist():
        if not any(inside[i, j] or inside[j, i] for j in kept):
            kept.append(i)
    return np.array(sorted(kept), dtype=np.int64)


def part(
    cluster: Cluster,
    centre: NDArray,
    lo: NDArray,
    hi: NDArray,
    rgb: NDArray,
    hsl: NDArray,
    edge: float,
    min_voxels: int,
) -> list[Cluster]:
    """The cluster's parts, one per claimant (``centre``, box ``lo``-``hi``, colour), or the cluster alone."""
    voxels = np.asarray(cluster.voxels, dtype=np.int64).reshape(-1, 3)
    if len(centre) < 2 or len(voxels) < 2 * min_voxels:
        return [cluster]
    points = (voxels + 0.5) * edge
    dist = _distance_to_boxes(points, lo, hi)
    dist += 1e-3 * np.linalg.norm(points[:, None, :] - centre[None, :, :], axis=2)  # ties to the nearer centre
    active = np.ones(len(centre), dtype=bool)
    while True:
        owner = np.where(active[None, :], dist, np.inf).argmin(axis=1)
        sizes = np.bincount(owner, minlength=len(centre))
        small = active & (sizes < min_voxels)
        if active.sum() < 2 or not small.any():
            break
        active[np.flatnonzero(small)[np.argmin(sizes[small])]] = False
    if active.sum() < 2:
        return [cluster]
    weights = np.asarray(cluster.voxel_points)
    has_weights = len(weights) == len(voxels)
    out = []
    for k in np.flatnonzero(active):
        mine = owner == k
        out.append(_piece(cluster, voxels[mine], weights[mine] if has_weights else weights[:0], (rgb[k], hsl[k]), edge))
    return out


def _piece(cluster: Cluster, voxels: NDArray, points: NDArray, colour: tuple[NDArray, NDArray], edge: float) -> Cluster:
    """A part of ``cluster``: its own voxels and geometry, the colour of the track that claimed it."""
    centres = (voxels + 0.5) * edge
    lo, hi = centres.min(axis=0) - 0.5 * edge, centres.max(axis=0) + 0.5 * edge
    cells = voxels.max(axis=0) - voxels.min(axis=0) + 1
    return Cluster(
        id=cluster.id,
        voxels=np.ascontiguousarray(voxels, dtype=np.int32),
        voxel_count=len(voxels),
        voxel_points=np.ascontiguousarray(points, dtype=np.int32),
        color_mean_rgb=np.asarray(colour[0], dtype=np.float32),
        color_var_rgb=cluster.color_var_rgb,
        color_mean_hsl=np.asarray(colour[1], dtype=np.float32),
        color_var_hsl=cluster.color_var_hsl,
        bbox_min=lo,
        bbox_max=hi,
        centroid=np.median(centres, axis=0),
        density=float(len(voxels)) / float(np.prod(cells.astype(np.float64))),
        volume=len(voxels) * edge**3,
        floor_m=cluster.floor_m + float(lo[2] - cluster.bbox_min[2]),  # the road as level under the cluster
    )


def part_shared(
    clusters: list[Cluster],
    centre: NDArray,
    lo: NDArray,
    hi: NDArray,
    rgb: NDArray,
    hsl: NDArray,
    rank: NDArray,
    edge: float,
    rule: Parting,
    whole: Callable[[Cluster], bool] | None = None,
) -> tuple[list[Cluster], int]:
    """Every cluster two claimants' centres lie in, parted (``part``) unless ``whole``; and how many were."""
    if len(centre) < 2 or not clusters:
        return clusters, 0
    box_lo = np.array([c.bbox_min for c in clusters], dtype=np.float64)
    box_hi = np.array([c.bbox_max for c in clusters], dtype=np.float64)
    inside = _inside(centre, box_lo, box_hi)  # [claimant, cluster]
    shared = set(np.flatnonzero(inside.sum(axis=0) >= 2).tolist())
    if not shared:
        return clusters, 0
    out: list[Cluster] = []
    parted = 0
    for j, c in enumerate(clusters):
        mine = np.flatnonzero(inside[:, j]) if j in shared else np.zeros(0, dtype=np.int64)
        if len(mine) >= 2:
            mine = mine[distinct(centre[mine], lo[mine], hi[mine], rank[mine])]
        if len(mine) < 2 or (whole is not None and whole(c)):
            out.append(c)
            continue
        pieces = part(c, centre[mine], lo[mine], hi[mine], rgb[mine], hsl[mine], edge, rule.min_voxels)
        parted += len(pieces) > 1
        out.extend(pieces)
    return out, parted


def claimants(t: TrackTable, rule: Parting) -> NDArray:
    """Which tracks claim: confirmed, old enough, of an object's size (and standing, if the rule says)."""
    recent = (t.queue == TRACKED) | ((t.queue == GHOST) & (t.misses <= 2))
    extent = t.bbox_max - t.bbox_min
    claim = recent & (t.age >= rule.min_age) & (extent[:, 0:2].max(axis=1) <= rule.max_extent_m)
    return claim & ~t.moving if rule.standing_only else claim


def part_tracked(
    clusters: list[Cluster], t: TrackTable, rule: Parting, edge: float, whole: Callable[[Cluster], bool] | None = None
) -> tuple[list[Cluster], set[int], int]:
    """The clusters with those the tracks' claimants share parted; the new parts, by identity; how many were parted.

    A claimant's box is where it was last seen, not where its filter expects it: a track sliding
    along a hedge would otherwise claim the voxels ahead of it and measure its own slide.
    """
    claim = claimants(t, rule)
    if claim.sum() < 2:
        return clusters, set(), 0
    out, n = part_shared(
        clusters, t.centroid[claim], t.bbox_min[claim], t.bbox_max[claim],
        t.rgb[claim], t.hsl[claim], t.age[claim].astype(np.float64), edge, rule, whole,
    )  # fmt: skip
    given = {id(c) for c in clusters}
    return out, {id(p) for p in out if id(p) not in given}, n


def cut_by_view(pose: NDArray, edge: float, view: NDArray, margin: float) -> Callable[[Cluster], bool]:
    """Whether the image's side edge cuts a cluster (anchor.py): its parts' ends there slide with the vehicle."""

    def cut(cluster: Cluster) -> bool:
        return bool(anchors([cluster], np.asarray(cluster.centroid)[None, :], pose, edge, view, margin)[4][0])

    return cut


def part_covariance(extent: NDArray, parted: NDArray, doubt: float) -> NDArray:
    """(m, 3, 3) what a part's centroid is doubted by, a share of its extent: where it ends is the parting's guess."""
    out = np.zeros((len(extent), 3, 3))
    if doubt > 0.0 and parted.any():
        idx = np.arange(3)
        out[:, idx, idx] = np.where(parted[:, None], (doubt * extent) ** 2, 0.0)
    return out
