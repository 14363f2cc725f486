"""The voxel mapper core on hand-built clouds: boxes, roads, grades and overhangs of known shape."""

from __future__ import annotations

import colorsys

import numpy as np
import pytest

from common.codec import decode, encode
from common.config import Config
from common.errors import ConfigError, InputError
from common.geometry import make_pose, rot_z
from common.messages import Clusters, EgoMotion, GroundTruthObject, GroundTruthObjects, PointCloud
from services.tracker import Tracker
from services.voxel_mapper import VoxelMapper
from services.voxel_mapper.colour import hsl_of
from services.voxel_mapper.flood_fill import neighbour_deltas, touching_pairs
from services.voxel_mapper.overhang import Overhang, frame_rows, overhangs
from services.voxel_mapper.terrain import TerrainProfile
from services.voxel_mapper.voxel_map import VoxelMap

RED, BLUE, GREY, GREEN, GLASS = (200, 40, 30), (30, 50, 190), (110, 110, 105), (40, 190, 60), (60, 70, 90)
#: no linkage of parts at all, neither the share rule nor the learned one: the flood fill's colours alone
COLOUR_ALONE: dict[str, object] = {"join_share": 2.0, "join_model": ""}


def box(lo: tuple[float, float, float], hi: tuple[float, float, float], colour: tuple[int, int, int],
        step: float = 0.04, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points on the six faces of an axis-aligned box, colour with +-6 levels of noise."""
    lo_a, hi_a = np.array(lo), np.array(hi)
    faces = []
    for axis in range(3):
        u, v = [a for a in range(3) if a != axis]
        gu = np.arange(lo_a[u], hi_a[u] + 1e-9, step)
        gv = np.arange(lo_a[v], hi_a[v] + 1e-9, step)
        mu, mv = np.meshgrid(gu, gv, indexing="ij")
        for side in (lo_a[axis], hi_a[axis]):
            face = np.empty((mu.size, 3))
            face[:, axis], face[:, u], face[:, v] = side, mu.ravel(), mv.ravel()
            faces.append(face)
    pts = np.concatenate(faces)
    return pts.astype(np.float32), noisy_colour(colour, len(pts), seed)


def noisy_colour(colour: tuple[int, int, int], n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(np.array(colour) + rng.integers(-6, 7, (n, 3)), 0, 255).astype(np.uint8)


def road(grade: float = 0.0, step: float = 0.08, x_max: float = 28.7) -> tuple[np.ndarray, np.ndarray]:
    """A road plane z = grade * x over the volume, with 2 cm of height noise."""
    xs, ys = np.meshgrid(np.arange(0.0, x_max, step), np.arange(-8.2, 8.2, step), indexing="ij")
    rng = np.random.default_rng(1)
    z = grade * xs + rng.normal(0.0, 0.02, xs.shape)
    pts = np.stack([xs.ravel(), ys.ravel(), z.ravel()], axis=1)
    return pts.astype(np.float32), noisy_colour(GREY, len(pts), 2)


def cloud(*parts: tuple[np.ndarray, np.ndarray], frame_id: int = 0) -> PointCloud:
    return PointCloud(frame_id=frame_id, stamp_ns=frame_id * 100_000_000,
                      points=np.concatenate([p for p, _ in parts]), colors=np.concatenate([c for _, c in parts]))


def ego(pose: np.ndarray | None = None, frame_id: int = 0, epoch: int = 0, valid: bool = True) -> EgoMotion:
    return EgoMotion(frame_id=frame_id, stamp_ns=frame_id * 100_000_000, pose=np.eye(4) if pose is None else pose,
                     valid=valid, world_epoch=epoch)


def mapper(**voxel: object) -> VoxelMapper:
    cfg = Config()
    for key, value in voxel.items():
        setattr(cfg.voxel, key, value)
    return VoxelMapper.from_config(cfg)


def test_hsl_matches_colorsys() -> None:
    rgb = np.random.default_rng(3).integers(0, 256, (200, 3), dtype=np.uint8)
    ours = hsl_of(rgb)
    for (r, g, b), (h, s, lum) in zip(rgb / 255.0, ours, strict=True):
        ch, cl, cs = colorsys.rgb_to_hls(r, g, b)
        assert (h, s, lum) == pytest.approx((ch, cs, cl), abs=1e-9)


def test_touching_boxes_of_different_colours_are_two_clusters() -> None:
    # Touching in voxels (cells 31 and 32 along x) without sharing a face a camera could not see anyway.
    out = mapper().process(cloud(road(), box((6, -1, 0), (7.95, 1, 1.5), RED), box((8, -1, 0), (10, 1, 1.5), BLUE)),
                           ego())
    assert len(out.clusters) == 2
    reds = [c for c in out.clusters if c.color_mean_rgb[0] > 0.5]
    blues = [c for c in out.clusters if c.color_mean_rgb[2] > 0.5]
    assert len(reds) == 1 and len(blues) == 1
    assert reds[0].centroid[0] == pytest.approx(7.0, abs=0.3)
    assert blues[0].centroid[0] == pytest.approx(9.0, abs=0.3)


def test_touching_boxes_of_one_colour_are_one_cluster() -> None:
    out = mapper().process(cloud(road(), box((6, -1, 0), (8, 1, 1.5), RED), box((8, -1, 0), (10, 1, 1.5), RED, seed=5)),
                           ego())
    assert len(out.clusters) == 1
    c = out.clusters[0]
    assert c.bbox_min[0] == pytest.approx(6.0, abs=0.15) and c.bbox_max[0] == pytest.approx(10.0, abs=0.15)
    assert c.voxel_count == len(c.voxels)
    assert c.volume == pytest.approx(c.voxel_count * 0.25**3)
    assert 0.0 < c.density <= 1.0
    assert np.all(c.color_var_rgb >= 0) and np.all(c.color_var_rgb < 0.01)


def test_reds_either_side_of_hue_zero_are_one_colour_with_circular_hue() -> None:
    # Hue 0.02 and 0.98 are both red: read as numbers they differ by nearly the whole circle.
    warm, cool = box((6, -1, 0), (8, 1, 1.5), (200, 50, 20)), box((8, -1, 0), (10, 1, 1.5), (200, 20, 50), seed=5)
    plain = mapper(**COLOUR_ALONE).process(cloud(road(), warm, cool), ego()).clusters  # the paper's reading
    assert len(plain) >= 2  # (and the voxels where they meet average to a cyan of their own)
    out = mapper(**COLOUR_ALONE, circular_hue=True).process(cloud(road(), warm, cool), ego())
    assert len(out.clusters) == 1
    hue, spread = out.clusters[0].color_mean_hsl[0], out.clusters[0].color_var_hsl[0]
    assert min(hue, 1.0 - hue) < 0.02  # red, not the cyan a plain mean of 0.02 and 0.98 gives
    assert spread < 0.05


def test_a_grey_wall_has_no_hue_to_split_it_with_circular_hue() -> None:
    # Noise of a few grey levels gives each point of a grey an arbitrary hue.
    wall = box((8, -4, 0), (8.5, 4, 2.5), (108, 108, 108), seed=7)
    out = mapper(**COLOUR_ALONE, circular_hue=True).process(cloud(road(), wall), ego())
    assert len(out.clusters) == 1
    assert out.clusters[0].color_var_hsl[0] > 0.5  # the hues cancel out: a spread, not a colour


def test_a_car_of_paint_and_glass_is_one_cluster() -> None:
    body, cabin = box((6, -0.9, 0.25), (10.3, 0.9, 0.9), RED), box((7.0, -0.8, 0.95), (9.4, 0.8, 1.45), GLASS)
    assert len(mapper(**COLOUR_ALONE).process(cloud(road(), body, cabin), ego()).clusters) >= 2  # colour alone
    out = mapper().process(cloud(road(), body, cabin), ego())
    assert len(out.clusters) == 1
    assert out.clusters[0].bbox_max[2] == pytest.approx(1.45, abs=0.15)


def test_faces_apart_along_the_line_of_sight_are_one_cluster() -> None:
    """A boot's back and the rear window 0.7 m behind it, with the boot lid unseen (as from 20 m)."""
    back = box((20.0, -0.9, 0.3), (20.05, 0.9, 0.95), RED)
    window = box((20.7, -0.8, 0.95), (20.75, 0.8, 1.45), GLASS)
    assert len(mapper(**COLOUR_ALONE).process(cloud(road(), back, window), ego()).clusters) >= 2
    assert len(mapper().process(cloud(road(), back, window), ego()).clusters) == 1


def test_a_grille_and_a_windscreen_one_layer_apart_are_one_cluster() -> None:
    """A car seen head-on from afar: grille below 0.9 m, windscreen from 1.05 m and 1 m further
    away, the bonnet between them seen edge-on, so no layer of voxels holds both."""
    front = box((20.0, -0.9, 0.3), (20.05, 0.9, 0.85), RED)
    screen = box((21.0, -0.8, 1.05), (21.05, 0.8, 1.55), GLASS)
    assert len(mapper(step_bridge_voxels=0).process(cloud(road(), front, screen), ego()).clusters) == 2
    (car,) = mapper().process(cloud(road(), front, screen), ego()).clusters
    assert car.bbox_min[2] < 0.4 and car.bbox_max[2] == pytest.approx(1.6, abs=0.1)
    # a board 2 m behind a low box is another object, however it lines up
    board = box((22.0, -0.8, 1.05), (22.05, 0.8, 1.55), GLASS)
    assert len(mapper().process(cloud(road(), front, board), ego()).clusters) == 2


def test_a_low_box_before_a_hedge_stays_apart_from_it() -> None:
    """The box's top looks up and away into the hedge, but the hedge stands on the road: it has no
    bottom in the air that looks back down to the box, so the step link is not mutual."""
    low = box((20.0, -0.9, 0.3), (20.8, 0.9, 0.7), RED)
    hedge = box((21.4, -3.0, 0.0), (22.4, 3.0, 2.2), GREEN)
    assert len(mapper().process(cloud(road(), low, hedge), ego()).clusters) == 2


def test_lone_noise_voxel_is_removed() -> None:
    rng = np.random.default_rng(6)
    speck = ((np.array([12.05, 3.05, 1.05]) + rng.random((30, 3)) * 0.15).astype(np.float32), noisy_colour(GREEN, 30))
    out = mapper().process(cloud(road(), box((6, -1, 0), (8, 1, 1.5), RED), speck), ego())
    assert len(out.clusters) == 1
    assert out.clusters[0].centroid[0] == pytest.approx(7.0, abs=0.3)
    assert out.voxel_count > 1000  # the speck and the road are in the map, only not clustered
    assert len(mapper(min_cluster_voxels=1).process(cloud(road(), box((6, -1, 0), (8, 1, 1.5), RED), speck),
                                                    ego()).clusters) == 2


def test_a_walker_of_two_small_colours_is_one_cluster() -> None:
    """Coat and trousers, 12 voxels each: parts below the noise limit are joined before it applies."""
    coat = box((10.05, -0.2, 1.0), (10.3, 0.2, 1.7), RED)
    legs = box((10.05, -0.2, 0.3), (10.3, 0.2, 0.95), BLUE)
    parts = mapper(min_cluster_voxels=1, **COLOUR_ALONE).process(cloud(road(), coat, legs), ego())
    assert sorted(c.voxel_count for c in parts.clusters) == [12, 12]
    # with no join and only big neighbours to aggregate into, both are dropped as noise
    assert mapper(join_min_voxels=20).process(cloud(road(), coat, legs), ego()).clusters == []
    out = mapper().process(cloud(road(), coat, legs), ego())
    assert len(out.clusters) == 1 and out.clusters[0].voxel_count == 24
    assert out.clusters[0].bbox_min[2] == pytest.approx(0.3, abs=0.1)
    assert out.clusters[0].bbox_max[2] == pytest.approx(1.7, abs=0.1)


def test_a_walker_before_a_facade_of_his_colour_is_cut_off_by_the_skyline() -> None:
    """Same grey, 0.15 m apart: one flood-fill cluster, but his columns end at 1.75 m, the facade's at 3.2."""
    facade = box((8.0, 3.0, 0.0), (16.0, 3.3, 3.2), GREY)
    walker = box((11.0, 2.35, 0.0), (11.3, 2.85, 1.75), GREY, seed=7)
    assert len(mapper(cut_tall_m=0.0).process(cloud(road(), facade, walker), ego()).clusters) == 1
    out = mapper().process(cloud(road(), facade, walker), ego())
    assert len(out.clusters) == 2
    small = out.clusters[1]
    assert small.centroid[:2] == pytest.approx((11.15, 2.6), abs=0.15)
    assert small.bbox_max[2] == pytest.approx(1.75, abs=0.2)
    assert out.clusters[0].bbox_min[1] > 2.85 - 0.1  # the facade keeps none of him


def test_small_cluster_touching_a_big_one_is_merged() -> None:
    rng = np.random.default_rng(4)
    patch_pts = (np.array([8.05, 0.05, 1.05]) + rng.random((40, 3)) * 0.15).astype(np.float32)  # one cell
    alone = mapper(min_cluster_voxels=1, **COLOUR_ALONE).process(cloud(road(), box((6, -1, 0), (8, 1, 1.5), RED),
                                                       (patch_pts, noisy_colour(GREEN, 40))), ego())
    assert len(alone.clusters) == 2  # without refinement (nor joining) the green voxel is its own cluster
    patch = (patch_pts, noisy_colour(GREEN, 40))
    out = mapper().process(cloud(road(), box((6, -1, 0), (8, 1, 1.5), RED), patch), ego())
    assert len(out.clusters) == 1
    assert out.clusters[0].voxel_count == alone.clusters[0].voxel_count + 1
    assert out.clusters[0].bbox_max[0] > 8.1


def test_small_pieces_touching_only_each_other_add_up_to_a_cluster() -> None:
    """Alg. IV-B.2 taken in turn: coat, trousers and head, none joined; only where near enough."""
    coat = box((10.05, -0.2, 1.0), (10.3, 0.2, 1.45), RED)
    legs = box((10.05, -0.2, 0.3), (10.3, 0.2, 0.95), BLUE)
    head = box((10.05, -0.1, 1.5), (10.3, 0.1, 1.7), GREEN)
    scene = cloud(road(), coat, legs, head)
    pieces = mapper(min_cluster_voxels=1, **COLOUR_ALONE).process(scene, ego())
    assert len(pieces.clusters) == 3 and sum(c.voxel_count for c in pieces.clusters) >= 20
    assert all(c.voxel_count < 20 for c in pieces.clusters)
    out = mapper(**COLOUR_ALONE, aggregate_in_turn_m=20.0).process(scene, ego())
    assert [c.voxel_count for c in out.clusters] == [sum(c.voxel_count for c in pieces.clusters)]
    assert mapper(**COLOUR_ALONE).process(scene, ego()).clusters == []  # only into a big one: all dropped
    assert mapper(**COLOUR_ALONE, aggregate_in_turn_m=9.0).process(scene, ego()).clusters == []  # he is at 10 m


def test_parts_one_empty_voxel_apart_touch_only_within_a_reach_of_two() -> None:
    """scripts/segmentation_ceiling.py's ``--reach``: the pairs a linkage over near parts would judge."""
    vmap = VoxelMap(0.25)
    left, _ = box((5.0, 0.0, 0.5), (5.2, 0.45, 1.2), RED)
    right, _ = box((5.55, 0.0, 0.5), (5.7, 0.45, 1.2), RED)  # from x 5.5: one empty voxel (5.25-5.5) between
    points = np.concatenate([left, right])
    vmap.integrate(points, noisy_colour(RED, len(points)), np.eye(4))
    labels = np.where(vmap.centroids[:, 0] < 5.3, 0, 1).astype(np.int32)
    assert len(touching_pairs(vmap, labels)) == 0
    assert touching_pairs(vmap, labels, neighbour_deltas(2)).tolist() == [[0, 1]]
    assert len(neighbour_deltas(2)) == 5**3 - 1


def test_static_box_stays_fixed_in_the_world_while_the_vehicle_moves() -> None:
    vm = mapper()
    world_box = box((10.1, 2.1, 0), (12.1, 3.6, 1.8), RED)  # off the voxel grid
    seen = []
    for k in range(4):
        pose = make_pose(rot_z(0.02 * k), [0.7 * k, 0.1 * k, 0.0])
        inv = np.linalg.inv(pose)
        local = (world_box[0] @ inv[:3, :3].T + inv[:3, 3]).astype(np.float32)
        out = vm.process(cloud(road(), (local, world_box[1]), frame_id=k), ego(pose, frame_id=k))
        assert len(out.clusters) == 1
        assert np.array_equal(out.ego_pose, pose)
        seen.append(out.clusters[0])
    first = {tuple(v) for v in seen[0].voxels}
    for c in seen[1:]:
        assert c.centroid == pytest.approx(seen[0].centroid, abs=0.05)
        overlap = len(first & {tuple(v) for v in c.voxels}) / len(first)
        assert overlap > 0.9  # the same world voxels, give or take cells the rotated road clips


def test_each_voxel_carries_the_points_this_frame_put_in_it() -> None:
    vm = mapper()
    red = box((10.1, 2.1, 0), (12.1, 3.6, 1.8), RED)
    for k in range(2):  # the same cloud twice: the counts are this frame's, not the voxel's history
        (c,) = vm.process(cloud(road(), red, frame_id=k), ego(frame_id=k)).clusters
        cells, per_cell = np.unique(np.floor(red[0] / vm.map.edge).astype(np.int64), axis=0, return_counts=True)
        expected = dict(zip(map(tuple, cells.tolist()), per_cell.tolist(), strict=True))
        assert c.voxel_points.shape == (c.voxel_count,)
        assert c.voxel_points.tolist() == [expected[tuple(v)] for v in c.voxels.tolist()]


def test_new_epoch_resets_the_map() -> None:
    vm = mapper(keep_frames=5)
    vm.process(cloud(road(), box((6, -1, 0), (8, 1, 1.5), RED)), ego())
    kept = vm.process(cloud(road(), frame_id=1), ego(frame_id=1))
    assert len(kept.clusters) == 1  # the decay keeps the unseen box
    reset = vm.process(cloud(road(), frame_id=2), ego(frame_id=2, epoch=1))
    assert reset.clusters == [] and reset.world_epoch == 1


def test_tilted_road_has_no_obstacles_in_terrain_mode_but_a_box_on_it_is_one() -> None:
    slope = road(grade=0.06)
    assert mapper(ground="terrain").process(cloud(slope), ego()).clusters == []
    assert len(mapper(ground="flat").process(cloud(slope), ego()).clusters) > 0  # what the flat road makes of it
    z0 = 0.06 * 15.0
    out = mapper(ground="terrain").process(cloud(slope, box((15, -1, z0), (17, 1, z0 + 1.5), BLUE)), ego())
    assert len(out.clusters) == 1
    assert out.clusters[0].centroid[0] == pytest.approx(16.0, abs=0.3)


def test_crest_has_no_obstacles_in_terrain_mode() -> None:
    up, down = road(grade=0.06, x_max=14.0), road(grade=-0.04, x_max=14.7)
    down_pts = down[0] + np.array([14.0, 0.0, 0.06 * 14.0], np.float32)
    assert mapper().process(cloud(up, (down_pts, down[1])), ego()).clusters == []


def test_cross_slope_has_no_obstacles_in_terrain_mode() -> None:
    """A road falling 5 cm per metre to the right (camber and camera roll, as on KITTI raw 0009)."""
    flat = road()
    tilted = (flat[0] + np.outer(flat[0][:, 1] * 0.05, [0.0, 0.0, 1.0]).astype(np.float32), flat[1])
    assert len(mapper(ground="flat").process(cloud(tilted), ego()).clusters) > 0
    assert mapper().process(cloud(tilted), ego()).clusters == []


def test_the_road_fit_does_not_change_with_points_off_the_road_or_their_order() -> None:
    """The fit samples points by their own coordinates: taking points high above the road out (as the
    sky mask takes out sky) and shuffling the rest leave the same road. Sampled by index, KITTI's road
    at 38 m moved when the sky mask took out two voxels' worth of sky."""
    graded = road(grade=0.03)
    camber = graded[0] + np.outer(graded[0][:, 1] * 0.04, [0.0, 0.0, 1.0]).astype(np.float32)
    sky = box((20, 3, 6), (22, 6, 9), RED)[0]
    with_sky = TerrainProfile().fit(np.concatenate([sky, camber]))
    ground, cross = with_sky.ground.copy(), with_sky.cross
    shuffled = camber[np.random.default_rng(5).permutation(len(camber))]
    alone = TerrainProfile().fit(shuffled)
    assert alone.cross == pytest.approx(cross, abs=1e-6) and cross == pytest.approx(0.04, abs=0.005)
    assert alone.ground == pytest.approx(ground, abs=1e-6)
    assert ground[-1] == pytest.approx(0.03 * 28.2, abs=0.05)


def test_overhanging_box_is_one_cluster_spanning_its_height() -> None:
    out = mapper().process(cloud(road(), box((9, -1.5, 1.5), (11, 1.5, 2.5), GREEN)), ego())
    assert len(out.clusters) == 1
    c = out.clusters[0]
    assert c.bbox_min[2] == pytest.approx(1.5, abs=0.25)
    assert c.bbox_max[2] == pytest.approx(2.5, abs=0.25)


def test_a_clusters_floor_is_its_lowest_voxel_above_the_road_even_on_a_slope() -> None:
    slope = road(grade=0.06)
    z0 = 0.06 * 15.0
    standing = box((15, -1, z0), (17, 1, z0 + 1.5), BLUE)
    hanging = box((15, 3, z0 + 1.6), (17, 5, z0 + 2.6), GREEN)  # a sign held 1.6 m over the road
    out = mapper(ground="terrain").process(cloud(slope, standing, hanging), ego())
    floors = sorted((c.centroid[1], c.floor_m) for c in out.clusters)
    assert len(floors) == 2
    assert floors[0][1] == pytest.approx(0.3, abs=0.15)  # the first voxel layer above the clearance
    assert floors[1][1] == pytest.approx(1.7, abs=0.2)  # a voxel's centre is half an edge above its face


def test_clusters_round_trip_through_the_codec() -> None:
    out = mapper().process(cloud(road(), box((6, -1, 0), (8, 1, 1.5), RED), frame_id=7), ego(frame_id=7))
    back = decode(encode(out), Clusters)
    assert back.frame_id == 7 and back.voxel_edge == 0.25
    assert np.array_equal(back.clusters[0].voxels, out.clusters[0].voxels)


def test_a_box_in_the_lookahead_is_passed_on_apart_and_followed_by_the_tracker() -> None:
    """A box centred 0.8 m beyond the volume's far end (28.7 m): clustered with a 1.5 m lookahead, but in
    ``Clusters.beyond``, not among the volume's clusters; without the lookahead not clustered at all."""
    cfg = Config()
    assert cfg.volume.lookahead_m == 1.5  # the default
    assert cfg.volume.seen().x_max == pytest.approx(30.2) and cfg.volume.x_max == pytest.approx(28.7)
    scene = (road(x_max=30.2), box((10, -1, 0), (11.5, 1, 1.5), RED), box((29.0, -1, 0), (30.0, 1, 1.5), BLUE))
    tracker = Tracker.from_config(cfg)
    ahead = VoxelMapper.from_config(cfg)
    for k in range(4):
        out = ahead.process(cloud(*scene, frame_id=k), ego(frame_id=k))
        obstacles = tracker.process(out, ego(frame_id=k))
    assert [round(float(c.centroid[0])) for c in out.clusters] == [11]
    assert [round(float(c.centroid[0]), 1) for c in out.beyond] == [pytest.approx(29.5, abs=0.2)]
    assert np.array_equal(decode(encode(out), Clusters).beyond[0].voxels, out.beyond[0].voxels)
    followed = sorted(round(float(o.centroid[0])) for o in obstacles.obstacles if o.state == "tracked")
    assert followed == [11, 30]  # the tracker follows the box beyond as it does the one inside
    cfg.volume.lookahead_m = 0.0
    plain = VoxelMapper.from_config(cfg).process(cloud(*scene), ego())
    assert [round(float(c.centroid[0])) for c in plain.clusters] == [11] and plain.beyond == []


def test_clusters_carry_the_image_side_edges_the_cloud_was_seen_within() -> None:
    # a camera 1 m ahead of the vehicle's origin and 0.3 m left of it sees bearings from -0.4 to 0.6
    slopes, ranges = np.linspace(-0.4, 0.6, 41), np.arange(2.0, 20.0, 0.5)
    s, r = np.meshgrid(slopes, ranges, indexing="ij")
    points = np.column_stack([1.0 + r.ravel(), 0.3 + (s * r).ravel(), np.zeros(s.size)]).astype(np.float32)
    seen = PointCloud(frame_id=0, stamp_ns=0, points=points, colors=noisy_colour(GREY, len(points)),
                      origin=np.array([1.0, 0.3, 1.5]))
    out = decode(encode(mapper().process(seen, ego())), Clusters)
    assert out.view == pytest.approx([1.0, 0.3, 0.6, -0.4])
    # a non-finite point (only ever built in process: the bus refuses them) leaves the edges as they are
    points[0, 1] = np.nan
    assert mapper().process(seen, ego()).view == pytest.approx([1.0, 0.3, 0.6, -0.4])
    # a cloud without points ahead has no edges: unknown, as in recordings made before the field
    empty = PointCloud(frame_id=1, stamp_ns=0, points=np.zeros((0, 3), np.float32), colors=np.zeros((0, 3), np.uint8))
    assert mapper().process(empty, ego(frame_id=1)).view.tolist() == [0.0, 0.0, 0.0, 0.0]


def test_invalid_egomotion_restarts_the_map_from_that_frame() -> None:
    vm = mapper(keep_frames=5)
    vm.process(cloud(road(), box((6, -1, 0), (8, 1, 1.5), RED)), ego())
    out = vm.process(cloud(road(), frame_id=1), ego(frame_id=1, valid=False))
    assert out.clusters == []  # the box kept by the decay is not fused under an unreliable pose
    assert out.voxel_count == mapper().process(cloud(road()), ego()).voxel_count


def test_empty_and_malformed_clouds() -> None:
    vm = mapper()
    empty = PointCloud(frame_id=3, stamp_ns=0, points=np.zeros((0, 3), np.float32), colors=np.zeros((0, 3), np.uint8))
    out = vm.process(empty, ego(frame_id=3))
    assert out.clusters == [] and out.voxel_count == 0 and out.frame_id == 3
    bad = np.full((6, 3), np.nan, np.float32)
    bad[:3] = 1e9  # beyond the 2^20-voxel world: skipped, not wrapped around
    assert vm.process(PointCloud(frame_id=4, stamp_ns=0, points=bad, colors=np.zeros((6, 3), np.uint8)),
                      ego(frame_id=4)).voxel_count == 0
    with pytest.raises(InputError, match="must both be Nx3"):
        vm.process(PointCloud(frame_id=5, stamp_ns=0, points=np.zeros((4, 3), np.float32),
                              colors=np.zeros((3, 3), np.uint8)), ego(frame_id=5))
    cfg = Config()
    cfg.voxel.ground = "hilly"
    with pytest.raises(ConfigError, match="flat' or 'terrain"):
        VoxelMapper.from_config(cfg)


def panel(x: float, per_voxel: int) -> tuple[np.ndarray, np.ndarray]:
    """A 2 x 1.25 m panel facing the camera at ``x`` with exactly ``per_voxel`` points in each 0.25 m cell."""
    rng = np.random.default_rng(8)
    cells = np.array([(j, k) for j in range(-4, 4) for k in range(1, 6)], dtype=float) * 0.25
    yz = (cells[:, None, :] + rng.uniform(0.02, 0.23, (len(cells), per_voxel, 2))).reshape(-1, 2)
    pts = np.column_stack([np.full(len(yz), x), yz]).astype(np.float32)
    return pts, noisy_colour(RED, len(pts))


def test_far_sparse_surface_needs_the_range_scaled_point_threshold() -> None:
    """5 points per voxel: below the fixed 8, above 8 * (15 / 23.1)^2 = 3.4 at 23 m, not above 8 at 9 m."""
    far, near = panel(23.1, 5), panel(9.1, 5)
    assert mapper(min_points_per_voxel=8, points_range_m=0.0).process(cloud(road(), far), ego()).clusters == []
    out = mapper(min_points_per_voxel=8, points_range_m=15.0).process(cloud(road(), far), ego())
    assert len(out.clusters) == 1 and out.clusters[0].voxel_count == 40
    assert mapper(min_points_per_voxel=8, points_range_m=15.0).process(cloud(road(), near), ego()).clusters == []


def gantry_truth() -> tuple[GroundTruthObjects, dict[int, Overhang]]:
    obj = GroundTruthObject(id=1, cls="barrier", center=np.array([15.0, 0.0, 1.6]), size=np.array([0.3, 6.25, 3.2]),
                            yaw=0.0, velocity=np.zeros(3), moving=False, visible_pixels=5000, visible_fraction=1.0)
    posts = np.array([[-0.125, 0.125, -3.125, -2.875], [-0.125, 0.125, 2.875, 3.125]])
    shape = Overhang(underside=2.8, top=3.2, over=np.array([[-0.15, 0.15, -3.0, 3.0]]), posts=posts)
    return GroundTruthObjects(frame_id=0, stamp_ns=0, objects=[obj]), {1: shape}


def test_overhang_measure_sees_the_span_and_what_is_beneath() -> None:
    colour = (220, 170, 30)
    posts = [box((14.875, side - 0.125, 0), (15.125, side + 0.125, 3.2), colour) for side in (-3.0, 3.0)]
    parts = [*posts, box((14.85, -3.0, 2.8), (15.15, 3.0, 3.2), colour, seed=3)]
    truth, shapes = gantry_truth()
    volume = Config().volume
    rows = frame_rows(mapper().process(cloud(road(), *parts), ego()), truth, np.eye(4), shapes, volume)
    assert len(rows) == 1 and rows[0]["spans"] and rows[0]["voxels_below"] == 0
    assert rows[0]["underside"] == pytest.approx(2.875, abs=0.01)  # centre of the beam's lowest cells over the lane
    under = box((14.5, -0.5, 0), (15.5, 0.5, 1.5), BLUE)  # something under the beam that no ground truth lists
    rows = frame_rows(mapper().process(cloud(road(), *parts, under), ego()), truth, np.eye(4), shapes, volume)
    assert rows[0]["spans"] and rows[0]["voxels_below"] > 0


def test_overhangs_of_the_hanging_scenario_are_the_sign_and_the_gantry() -> None:
    shapes = overhangs("hanging", 1, 3.5)
    assert sorted((round(s.underside, 2), round(s.top, 2)) for s in shapes.values()) == [(2.4, 3.5), (2.8, 3.2)]


def test_two_walkers_joined_by_smear_are_cut_apart_where_their_points_stand() -> None:
    # two people 1.1 m apart, the gap between them filled by a sparser sheet of smear of their colour
    coat = (40, 90, 160)
    walkers = [box((12.0, y, 0.0), (12.5, y + 0.5, 1.75), coat, seed=k) for k, y in enumerate((-0.8, 0.3))]
    smear = box((12.0, -0.3, 0.2), (12.5, 0.3, 1.5), coat, step=0.08, seed=5)
    frame = cloud(road(), *walkers, smear)
    whole = mapper(group_dense_share=0.0).process(frame, ego()).clusters
    cut = mapper().process(frame, ego()).clusters
    assert len(whole) == 1
    assert len(cut) == 2
    assert sorted(round(float(c.centroid[1]), 1) for c in cut) == pytest.approx([-0.5, 0.5], abs=0.15)


def test_a_car_and_a_gap_in_a_wall_are_not_cut_as_people() -> None:
    # a car's rear is one dense patch 1.8 m wide; a wall with a doorway is two dense patches each
    # wider than a person
    car = box((12.0, -0.9, 0.3), (16.0, 0.9, 1.5), BLUE)
    wall = [box((20.0, y0, 0.0), (20.5, y1, 2.0), BLUE, seed=2) for y0, y1 in ((3.0, 5.0), (5.6, 7.6))]
    sill = box((20.0, 5.0, 1.8), (20.5, 5.6, 2.0), BLUE, step=0.08, seed=4)
    assert len(mapper().process(cloud(road(), car, *wall, sill), ego()).clusters) == 2


def test_only_corners_that_have_lain_on_a_cluster_are_passed_on() -> None:
    # a red box ahead on the road; corner 1 on its face, corner 2 on the road, corner 3 in the air
    scene = (box((10.0, -0.5, 0.0), (11.0, 0.5, 1.5), RED), road())
    ids = np.array([1, 2, 3])
    on_box, on_road, in_air = [10.0, 0.1, 0.8], [6.0, 2.0, 0.01], [14.0, -3.0, 2.0]
    vm = mapper()

    def passed(corners: list[list[float]], frame: int) -> list[int]:
        c = cloud(*scene, frame_id=frame)
        c.keypoint_ids, c.keypoints = ids, np.array(corners, dtype=np.float32)
        c.keypoint_std = np.full(3, 0.05, np.float32)
        out = vm.process(c, ego(frame_id=frame))
        assert len(out.keypoints) == len(out.keypoint_std) == len(out.keypoint_ids)
        return out.keypoint_ids.tolist()

    assert passed([on_box, on_road, in_air], 0) == [1]
    # the box's corner strays a voxel off its surface (its own disparity): it is still passed on,
    # while the road's, now on the box, is passed on from here
    assert passed([[9.6, 0.1, 0.8], on_box, in_air], 1) == [1, 2]
    assert passed([in_air, in_air, in_air], 2) == [1, 2]


def test_slots_at_finds_the_voxel_a_point_lies_in() -> None:
    vm = mapper()
    vm.process(cloud(box((10.0, -0.5, 0.0), (11.0, 0.5, 1.5), RED)), ego())
    slots = vm.map.slots_at(np.array([[10.0, 0.1, 0.8], [20.0, 0.0, 0.5], [np.nan, 0.0, 0.0]]))
    assert slots[0] >= 0 and slots[1:].tolist() == [-1, -1]
    assert (vm.map.coords[slots[0]] == np.floor(np.array([10.0, 0.1, 0.8]) / vm.map.edge)).all()
