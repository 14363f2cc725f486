"""Pieces of one tracked object put back together before association.

The colour flood fill splits an object wherever its colour changes (a car's body and its windows,
a lorry's cab and box) and the split moves from frame to frame. One piece then keeps the track and
the others start tracks of their own, which move with the object and are reported as extra moving
obstacles, while the kept piece's centroid jumps as the pieces change (measured on synthetic
urban, crossing and overtake, seeds 1-2: a third to a half of all new tracks started within 2 m
of a track that had already taken another cluster that frame).

A track knows how big its object was; every cluster whose centroid falls inside the track's
predicted box (grown by ``margin``) is a piece of it, and two or more such pieces claimed by that
track alone are merged into one cluster. A piece claimed by two tracks is left as it is: which
object it belongs to is what association decides.

The box a track knows can hold more than one object: walkers side by side, or a walker passing
a kiosk, are one cluster while stereo smear joins them, and the track's box then covers them
all. Every piece inside that box used to be merged back, so the box never shrank and the walkers
who parted never got tracks of their own (synthetic crossing seed 2: 55 walker-frames with a
cluster of their own, centred on them, and no track). So only pieces whose boxes touch are merged
(chained by gaps of at most ``gap``, a little under half a voxel, single linkage): a car's body
and windows touch, while walkers a step apart stay apart. Tracker replays over the clusters of
urban, crossing, overtake and slope seeds 1-2: moving TP on urban-s2 68.8 -> 79.7 % with FP
7.8 -> 0 %, crossing-s2 15.3 -> 27.3 %, overtake-s2 88.1 / 11.9 -> 92.9 / 7.1 %, the other five
runs within a point and a half; gaps of 0.25-0.5 m did about as well there but cost KITTI
tracking 0001 a tenth of its stationary recall, 1 m lost urban-s2's gain
(docs/results/tracking.md, "Session 12").

Boxes still touch where voxels do not: the voxel map joins a facade and a pole 2 m in front of
it into one cluster, and a walker passing between them lies inside that box, touching it, frame
after frame (synthetic urban: 37 walker- and cyclist-frames of ten runs with a cluster of their
own, centred on them, gathered into a neighbour's track). So two pieces that both stand on the
group's floor must also touch column to column seen from above (``standing_links``), and an
acceptance track is held back inside a tracked box only if its cluster would have been gathered
(``stand_apart``). Moving recall, tracker replays: tuning seeds 1-6 69.7 -> 71.9 %, held-out
seeds 7-10 68.5 -> 71.4 % (docs/results/tracking.md, "Session 18").

Footprints touch too where stereo smear joins them: walkers crossing the road two or three
abreast, 1-2 m apart in range, each a cluster of its own colour 2-3 m long along the line of
sight. Their footprints touched, they were gathered into one track, and the others had none
(synthetic urban and crossing, tuning seeds: 52 walker-frames). A standing piece as tall as a
person and no wider than one (``Standing.upright_m``, ``thin_m``) is a whole object: two such are
never gathered, whatever touches. A car's pieces are wider, and a walker's legs and coat are
not each that tall (docs/results/tracking.md, "Session 20").

Nor is such a piece gathered with any other piece standing beside it into a slow track's box
(``Standing.alone_mps``): a walker passing a bin 0.1 m from it on the sidewalk is a cluster of his
own, but the bin's track took him in, frame after frame, and reported the pair standing between
them (synthetic urban-s9, walker 50 and bin 24). A vehicle's track is left out of it (faster than
``tracker.upright_alone_mps``): a car's tall piece can be as thin across the line of sight, and
it became a second moving track riding on the car (synthetic overtake). Held-out urban's moving
TP 79.6 -> 80.7 % (docs/results/tracking.md, "Session 45").
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.sparse.csgraph import connected_components

from common.messages import Cluster
from common.voxel_keys import pack_cells
from services.tracker.track import ACCEPTANCE, TRACKED, TrackTable

NDArray = npt.NDArray[Any]


def claims(centroids: NDArray, box_min: NDArray, box_max: NDArray, margin: float) -> NDArray:
    """(tracks x clusters) True where the cluster's centroid lies in the track's grown box."""
    lo, hi = box_min - margin, box_max + margin
    inside = np.ones((len(lo), len(centroids)), dtype=bool)
    for axis in range(3):  # one comparison per axis: np.all over a trailing axis of 3 took 80 us for 50 x 50
        inside &= (centroids[None, :, axis] >= lo[:, None, axis]) & (centroids[None, :, axis] <= hi[:, None, axis])
    return inside


def _pooled_points(pieces: list[Cluster]) -> np.ndarray:
    """The pieces' per-voxel point counts in the order of their pooled voxels; empty unless every piece has them."""
    per = [np.asarray(p.voxel_points) for p in pieces]
    if any(len(w) != len(np.asarray(p.voxels)) for w, p in zip(per, pieces, strict=True)):
        return np.zeros(0, dtype=np.int32)
    return np.concatenate(per).astype(np.int32)


def merge(pieces: list[Cluster], edge: float) -> Cluster:
    """One cluster out of several: voxels pooled, box joined, colour of the largest piece."""
    counts = np.array([p.voxel_count for p in pieces], dtype=np.float64)
    largest = pieces[int(np.argmax(counts))]
    bbox_min = np.min([p.bbox_min for p in pieces], axis=0)
    bbox_max = np.max([p.bbox_max for p in pieces], axis=0)
    centroid = (counts[:, None] * np.array([p.centroid for p in pieces])).sum(axis=0) / counts.sum()
    cells = max(float(np.prod((bbox_max - bbox_min) / edge)), 1.0)
    return Cluster(
        id=largest.id,
        voxels=np.concatenate([np.asarray(p.voxels) for p in pieces]),
        voxel_count=int(counts.sum()),
        voxel_points=_pooled_points(pieces),
        color_mean_rgb=largest.color_mean_rgb,
        color_var_rgb=largest.color_var_rgb,
        color_mean_hsl=largest.color_mean_hsl,
        color_var_hsl=largest.color_var_hsl,
        bbox_min=bbox_min,
        bbox_max=bbox_max,
        centroid=centroid,
        density=min(float(counts.sum()) / cells, 1.0),
        volume=float(sum(p.volume for p in pieces)),
        floor_m=min(p.floor_m for p in pieces),
    )


def near_boxes(box_min: NDArray, box_max: NDArray, gap: float) -> NDArray:
    """(boxes x boxes) True where two boxes are no more than ``gap`` apart."""
    between = np.maximum(box_min[:, None, :] - box_max[None, :, :], box_min[None, :, :] - box_max[:, None, :])
    return np.max(np.maximum(between, 0.0), axis=2) <= gap


def components(links: NDArray) -> list[NDArray]:
    """Groups joined by chains of links (single linkage), as index arrays."""
    n_groups, group = connected_components(links, directed=False)
    return [np.flatnonzero(group == g) for g in range(n_groups)]


#: the 27 offsets from a voxel to itself and its 26 neighbours.
_NEIGHBOURS = np.stack(np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)


def in_contact(voxels: list[NDArray], candidates: NDArray) -> NDArray:
    """(pieces x pieces) True where, among ``candidates``, a voxel of one is a 26-neighbour of the other's."""
    cells = [np.asarray(v, dtype=np.int64).reshape(-1, 3) for v in voxels]
    touch = np.eye(len(cells), dtype=bool)
    for i, j in zip(*np.nonzero(np.triu(candidates, k=1)), strict=True):
        a, b = _facing(cells[i], cells[j]), _facing(cells[j], cells[i])
        if len(a) and len(b):
            reach = pack_cells((a[:, None, :] + _NEIGHBOURS).reshape(-1, 3))
            touch[i, j] = touch[j, i] = bool(np.isin(pack_cells(b), reach).any())
    return touch


def _facing(cells: NDArray, other: NDArray) -> NDArray:
    """The voxels of ``cells`` within one step of ``other``'s box: the only ones that can touch it."""
    near = np.all((cells >= other.min(axis=0) - 1) & (cells <= other.max(axis=0) + 1), axis=1)
    return cells[near]


def footprint(voxels: NDArray) -> NDArray:
    """The columns a cluster's voxels stand in, as voxels at height 0."""
    columns = np.unique(np.asarray(voxels, dtype=np.int64).reshape(-1, 3)[:, 0:2], axis=0)
    return np.column_stack([columns, np.zeros(len(columns), dtype=np.int64)])


@dataclass(frozen=True)
class Standing:
    """When pieces standing side by side are objects of their own (standing_links).

    The shape it calls upright, a person's or a pole's, is also what the tracker follows and
    labels by its own noise (core.py, labelling.py).
    """

    floor_m: float = -1.0  # a box reaching this near the group's lowest stands on its floor; < 0: off
    upright_m: float = 0.0  # a box this tall (m) ...
    thin_m: float = 0.0  # ... and this narrow in x or y (m) is a whole person or pole; 0: off
    alone_mps: float = 0.0  # ... nor links to any standing piece in the box of a track slower than this; 0: off

    def upright(self, extent: NDArray) -> NDArray:
        """Which boxes of these extents (n, 3) are a person's or a pole's."""
        extent = np.asarray(extent, dtype=np.float64).reshape(-1, 3)
        if self.upright_m <= 0.0 or self.thin_m <= 0.0:
            return np.zeros(len(extent), dtype=bool)
        return (extent[:, 2] >= self.upright_m) & (np.minimum(extent[:, 0], extent[:, 1]) <= self.thin_m)

    def whole(self, pieces: list[Cluster], standing: NDArray, sight: Sight | None = None) -> NDArray:
        """Which standing pieces are a whole upright object: by their boxes, or seen from ``sight``.

        Seen from the camera, a piece is as wide as its voxels spread across the line of sight:
        a walker's smear along that line makes his box as long as a car's (3-4 m at 20-30 m) and
        a box test let a facade's track take him in.
        """
        extent = np.array([np.asarray(p.bbox_max) - np.asarray(p.bbox_min) for p in pieces], dtype=np.float64)
        if sight is not None:
            for i, p in enumerate(pieces):
                if standing[i] and extent[i, 2] >= self.upright_m and len(p.voxels):
                    extent[i, 0:2] = sight.width(np.asarray(p.voxels))
        return standing & self.upright(extent)


@dataclass(frozen=True)
class Sight:
    """Where the camera stood, and the voxel edge: what a piece's width across its line of sight needs."""

    eye: NDArray  # world position of the camera (3,)
    edge: float

    def width(self, voxels: NDArray) -> float:
        """How far the voxels spread (5-95 %) across the line from the eye to their middle (m)."""
        xy = (np.asarray(voxels, dtype=np.float64).reshape(-1, 3)[:, 0:2] + 0.5) * self.edge
        ray = xy.mean(axis=0) - self.eye[0:2]
        ray /= max(float(np.linalg.norm(ray)), 1e-9)
        lo, hi = np.percentile(xy @ np.array([-ray[1], ray[0]]), [5.0, 95.0])
        return float(hi - lo)


#: standing pieces not told apart: boxes alone decide.
APART_BY_BOX = Standing()


def standing_links(pieces: list[Cluster], near: NDArray, standing: Standing, sight: Sight | None = None) -> NDArray:
    """Which of the ``near`` links a group of pieces keeps when two standing on its floor must touch.

    A piece whose box reaches down to within ``standing.floor_m`` of the group's lowest piece stands on
    the ground beside the others: a walker between a facade and a pole whose boxes the voxel map
    had joined. It is part of another such piece only if their footprints touch, column beside
    column seen from above: objects side by side on the ground stand apart there, while a car's
    pieces stacked around the hole of its windows do not (3-D contact split those on synthetic
    urban seed 7). A piece held higher (a tree's crown, a facade's upper storey) cannot stand
    alone and joins by its box as before. Two standing pieces that are each upright
    (``Standing.whole``) never link, touch as they may. Boxes decide alone when a piece carries no
    voxels.
    """
    voxels = [np.asarray(p.voxels) for p in pieces]
    if standing.floor_m < 0.0 or any(len(v) == 0 for v in voxels):
        return near
    bottom = np.array([p.bbox_min[2] for p in pieces], dtype=np.float64)
    on_floor = bottom <= bottom.min() + standing.floor_m
    both = near & on_floor[:, None] & on_floor[None, :]
    links = near & (~both | in_contact([footprint(v) for v in voxels], both))
    whole = standing.whole(pieces, on_floor, sight)
    apart = (whole[:, None] | whole[None, :]) & both if standing.alone_mps > 0.0 else whole[:, None] & whole[None, :]
    return links & ~(apart & ~np.eye(len(pieces), dtype=bool))


def stand_apart(whole: Cluster, piece: Cluster, standing: Standing, sight: Sight | None = None) -> bool:
    """Whether a piece near a known object's cluster is an object of its own (standing_links)."""
    return not standing_links([whole, piece], np.ones((2, 2), dtype=bool), standing, sight)[0, 1]


def gather(
    clusters: list[Cluster],
    box_min: NDArray,
    box_max: NDArray,
    margin: float,
    edge: float,
    gap: float = -1.0,
    standing: Standing = APART_BY_BOX,
    sight: Sight | None = None,
    speed: NDArray | None = None,
) -> list[Cluster]:
    """The clusters with each track's exclusive pieces merged; order otherwise kept. ``speed`` is
    each track's (m/s): only a slower one's box than ``standing.alone_mps`` keeps an upright piece
    alone (None: every one's)."""
    if len(clusters) < 2 or len(box_min) == 0:
        return clusters
    centroids = np.array([c.centroid for c in clusters], dtype=np.float64)
    claimed = claims(np.where(np.isfinite(centroids), centroids, np.inf), box_min, box_max, margin)
    exclusive = claimed & (claimed.sum(axis=0) == 1)[None, :]
    rows = np.flatnonzero(exclusive.sum(axis=1) >= 2)
    groups = [np.flatnonzero(exclusive[row]) for row in rows]
    if gap >= 0.0:
        lo = np.array([c.bbox_min for c in clusters], dtype=np.float64)
        hi = np.array([c.bbox_max for c in clusters], dtype=np.float64)
        parted: list[NDArray] = []
        fast = dataclasses.replace(standing, alone_mps=0.0)
        for row, g in zip(rows, groups, strict=True):
            rule = standing if speed is None or speed[row] < standing.alone_mps else fast
            links = standing_links([clusters[i] for i in g], near_boxes(lo[g], hi[g], gap), rule, sight)
            parted += [g[part] for part in components(links) if len(part) >= 2]
        groups = parted
    if not groups:
        return clusters
    merged_into: dict[int, Cluster] = {}
    absorbed: set[int] = set()
    for members in groups:
        first = int(members[0])
        merged_into[first] = merge([clusters[i] for i in members.tolist()], edge)
        absorbed.update(int(i) for i in members[1:])
    return [merged_into.get(i, c) for i, c in enumerate(clusters) if i not in absorbed]


def inside_known(
    t: TrackTable, seen: NDArray, piece_of: dict[int, Cluster], sight: Sight, margin: float, standing: Standing
) -> NDArray:
    """Acceptance tracks whose centroid lies in the box (grown by ``margin``; < 0: none) of a tracked
    object seen this frame.

    Such a track is a piece the merge of ``gather`` missed (it was outside the predicted box);
    promoted, it would be a second obstacle on one object, moving with it. Unless the two clusters
    (``piece_of``, by track row) stand apart as ``stand_apart`` judges.
    """
    held = np.zeros(len(t), dtype=bool)
    young = t.queue == ACCEPTANCE
    known = seen & (t.queue == TRACKED)
    if margin < 0.0 or not young.any() or not known.any():
        return held
    inside = claims(t.centroid[young], t.bbox_min[known], t.bbox_max[known], margin)
    known_rows, young_rows = np.flatnonzero(known), np.flatnonzero(young)
    for k, y in zip(*np.nonzero(inside), strict=True):
        whole, piece = piece_of.get(int(known_rows[k])), piece_of.get(int(young_rows[y]))
        if whole is not None and piece is not None and stand_apart(whole, piece, standing, sight):
            inside[k, y] = False
    held[young] = inside.any(axis=0)
    return held
