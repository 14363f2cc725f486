"""A cluster two known objects share is parted between their tracks (services/tracker/parting.py)."""

from __future__ import annotations

import colorsys
import dataclasses

import numpy as np

from common.config import Config
from common.messages import Cluster, Clusters, EgoMotion
from services.tracker import Tracker
from services.tracker.parting import Parting, distinct, part_shared

EDGE = 0.25
PERIOD_NS = 100_000_000


def block(lo: tuple[float, float, float], hi: tuple[float, float, float]) -> np.ndarray:
    """Integer voxels filling the box lo-hi (m)."""
    axes = [np.arange(int(np.floor(a / EDGE)), int(np.ceil(b / EDGE))) for a, b in zip(lo, hi, strict=True)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def voxel_cluster(cid: int, voxels: np.ndarray, rgb: tuple[float, float, float] = (0.6, 0.2, 0.2)) -> Cluster:
    """A cluster made of ``voxels``, geometry as the mapper gives it (median centroid, box of voxel centres)."""
    centres = (voxels + 0.5) * EDGE
    hsl = colorsys.rgb_to_hls(*rgb)
    return Cluster(
        id=cid,
        voxels=voxels.astype(np.int32),
        voxel_count=len(voxels),
        voxel_points=np.full(len(voxels), 5, dtype=np.int32),
        color_mean_rgb=np.asarray(rgb, dtype=np.float32),
        color_var_rgb=np.zeros(3, dtype=np.float32),
        color_mean_hsl=np.asarray((hsl[0], hsl[2], hsl[1]), dtype=np.float32),
        color_var_hsl=np.zeros(3, dtype=np.float32),
        bbox_min=centres.min(axis=0) - EDGE / 2,
        bbox_max=centres.max(axis=0) + EDGE / 2,
        centroid=np.median(centres, axis=0),
        density=0.5,
        volume=len(voxels) * EDGE**3,
    )


# a walker 0.5 x 0.5 x 1.75 m at x 12, a bin 0.75 x 0.75 x 1 m at x 14, and the smear between them
WALKER = block((11.75, 0.0, 0.0), (12.25, 0.5, 1.75))
BIN = block((13.75, 0.0, 0.0), (14.5, 0.75, 1.0))
SMEAR = block((12.25, 0.0, 0.0), (13.75, 0.5, 1.0))


def boxes(*parts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centres, minima and maxima (m) of the voxel sets, as a claimant's last box."""
    centres = [(p + 0.5) * EDGE for p in parts]
    lo = np.array([c.min(axis=0) - EDGE / 2 for c in centres])
    hi = np.array([c.max(axis=0) + EDGE / 2 for c in centres])
    return np.array([np.median(c, axis=0) for c in centres]), lo, hi


def test_a_cluster_two_claimants_lie_in_is_parted_between_them() -> None:
    joined = voxel_cluster(0, np.concatenate([WALKER, SMEAR, BIN]))
    centre, lo, hi = boxes(WALKER, BIN)
    colours = np.array([[0.2, 0.2, 0.8], [0.3, 0.6, 0.3]])
    out, n = part_shared([joined], centre, lo, hi, colours, colours, np.array([9.0, 7.0]), EDGE, Parting(8))
    assert n == 1 and len(out) == 2
    assert sum(p.voxel_count for p in out) == joined.voxel_count
    # the joined cluster's centroid lies on neither; each part's lies in its claimant's box
    assert not any(np.all((joined.centroid >= lo[k]) & (joined.centroid <= hi[k])) for k in range(2))
    for k, piece in enumerate(out):
        assert np.all((piece.centroid >= lo[k]) & (piece.centroid <= hi[k]))
        assert np.allclose(piece.color_mean_rgb, colours[k])


def test_a_cluster_is_not_parted_for_one_claimant_or_the_same_object_twice() -> None:
    joined = voxel_cluster(0, np.concatenate([WALKER, SMEAR, BIN]))
    centre, lo, hi = boxes(WALKER, BIN)
    grey = np.full((2, 3), 0.5)
    alone, n = part_shared([joined], centre[:1], lo[:1], hi[:1], grey[:1], grey[:1], np.ones(1), EDGE, Parting(8))
    assert n == 0 and alone == [joined]
    # a second claimant whose centre lies in the first's box is that object again: the older claims alone
    twice = np.array([centre[0], centre[0] + [0.1, 0.0, 0.0]])
    assert distinct(
        twice, np.repeat(lo[:1], 2, axis=0), np.repeat(hi[:1], 2, axis=0), np.array([3.0, 5.0])
    ).tolist() == [1]
    out, n = part_shared([joined], twice, np.repeat(lo[:1], 2, axis=0), np.repeat(hi[:1], 2, axis=0), grey, grey,
                         np.array([3.0, 5.0]), EDGE, Parting(8))  # fmt: skip
    assert n == 0 and out == [joined]


def test_a_part_too_small_to_be_an_object_withdraws_its_claimant() -> None:
    speck = block((14.0, 0.0, 0.0), (14.25, 0.25, 0.5))  # 2 voxels: no object
    thin = block((12.25, 0.25, 0.5), (14.0, 0.5, 0.75))  # 7 voxels of smear, 3 of them nearer the speck
    joined = voxel_cluster(0, np.concatenate([WALKER, thin, speck]))
    centre, lo, hi = boxes(WALKER, speck)
    grey = np.full((2, 3), 0.5)
    out, n = part_shared([joined], centre, lo, hi, grey, grey, np.ones(2), EDGE, Parting(8))
    assert n == 0 and out == [joined]


def tracker(part_min_voxels: int) -> Tracker:
    cfg = Config()
    cfg = dataclasses.replace(cfg, tracker=dataclasses.replace(cfg.tracker, part_min_voxels=part_min_voxels))
    return Tracker.from_config(cfg)


def run(t: Tracker, merged_from: int, frames: int = 14) -> list[dict[int, np.ndarray]]:
    """A walker and a bin seen apart, then (from ``merged_from``) as one cluster strung by smear."""
    out = []
    for f in range(frames):
        if f < merged_from:
            clusters = [voxel_cluster(0, WALKER, (0.2, 0.2, 0.8)), voxel_cluster(1, BIN, (0.3, 0.6, 0.3))]
        else:
            clusters = [voxel_cluster(0, np.concatenate([WALKER, SMEAR, BIN]), (0.3, 0.6, 0.3))]
        msg = Clusters(frame_id=f, stamp_ns=f * PERIOD_NS, clusters=clusters, voxel_edge=EDGE, world_epoch=0,
                       ego_pose=np.eye(4))  # fmt: skip
        obstacles = t.process(msg, EgoMotion(frame_id=f, stamp_ns=f * PERIOD_NS, pose=np.eye(4), valid=True))
        out.append({o.id: np.asarray(o.centroid) for o in obstacles.obstacles if o.state == "tracked"})
    return out


def test_two_tracked_objects_strung_together_keep_their_own_positions() -> None:
    walker_at, bin_at = (WALKER + 0.5).mean(axis=0) * EDGE, (BIN + 0.5).mean(axis=0) * EDGE

    def both_found(frame: dict[int, np.ndarray]) -> bool:
        return all(any(np.linalg.norm((c - at)[0:2]) < 0.3 for c in frame.values()) for at in (walker_at, bin_at))

    on = tracker(8)
    parted = run(on, merged_from=8)
    assert all(both_found(f) for f in parted[2:8])  # tracked apart first
    assert all(both_found(f) for f in parted[8:])  # and still, each at its own place, once joined
    assert on.counters["parted"] == len(parted) - 8
    whole = run(tracker(0), merged_from=8)
    assert not all(both_found(f) for f in whole[8:])  # without parting one of them is lost or moved
