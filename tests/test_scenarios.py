"""The synthetic scenarios: camera geometry, truth disparity against a real matcher, determinism,
every scenario rendering with ground truth, and clear errors."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from common.errors import ConfigError
from common.geometry import invert
from common.messages import OPEN_CLASSES, GroundTruthDisparity, GroundTruthObjects, StereoFrame
from common.recording import open_recording
from common.scenarios.catalogue import SCENARIOS, build
from common.scenarios.clearance import shared_volume
from common.scenarios.props import box, gantry, pedestrian
from common.scenarios.raycast import Packed
from common.scenarios.render import Renderer, Rig
from common.scenarios.road import Road
from common.scenarios.simulate import frame_messages, simulate_to_file
from common.scenarios.street import keep_pace
from common.scenarios.world import EgoProfile, Look, Material, Part, Thing, World
from common.scenarios.world import Path as RoadPath
from services.cli import main as cli_main


def _one_box_world(left: float = 1.013) -> World:
    """A flat road and one 1 x 1 x 3.03 m box whose near face is 10 m ahead, 0.513..1.513 m to the left.

    Edges fall between pixel centres, so no pixel sits exactly on a boundary.
    """
    part = Part((0.0, 0.0, 1.515), (1.0, 1.0, 3.03), Material((0.8, 0.2, 0.2)))
    thing = Thing(1, "wall", (part,), (1.0, 1.0, 3.03), RoadPath(10.5, left))
    look = Look(noise_sigma=0.0, blur_sigma=0.0)
    return World("test", Road(y0=0.0), (thing,), EgoProfile((0.0, 1.0), (0.0, 0.0), d=0.0), look)


def test_known_point_appears_at_predicted_pixel_and_disparity() -> None:
    rig = Rig()
    renderer = Renderer(_one_box_world(), rig)
    out = renderer.render(0.0, np.random.default_rng(0))
    # near face at Z = 10 m, camera x from -1.513 to -0.513 m -> u = 600 * X / 10 + 320 in [229.2, 269.2];
    # beyond it the inner side face (y = 0.513 m, Z 10..11 m) shows up to u = 320 - 307.8 / 11 = 292.0
    row = out.object_ids[240]
    assert row[229] == -1 and row[230] == 1 and row[291] == 1 and row[293] == -1
    assert out.depth[240, 250] == pytest.approx(10.0, abs=1e-4)
    assert out.disparity[240, 250] == pytest.approx(600 * 0.4 / 10.0, abs=1e-3)
    # the box's top (z = 3.03 m, 1.53 m above the camera) is at v = 240 - 600 * 1.53 / 10 = 148.2
    column = out.object_ids[:, 250]
    assert column[148] == -1 and column[149] == 1
    # the right camera sees the same face shifted left by the disparity, 24 px: from u = 205.2
    _, right_pose = renderer.camera_poses(out.ego_pose)
    right = renderer.cast(right_pose, Packed.of(renderer.boxes(out.states, out.ego_pose)[0]))
    right_row = right.obj.reshape(rig.height, rig.width)[240]
    assert right_row[205] == -1 and right_row[206] == 1
    assert out.visible_fraction[1] == pytest.approx(1.0, abs=0.02)
    # row 320 left of the box: road at Z = 600 * 1.5 / 80 = 11.25 m (disparity 21.33), hidden from the
    # right camera by the box (disparity 24) over 24 - 21.33 = 2.67 px left of its edge at u = 229.2
    band = out.disparity[320]
    assert np.isnan(band[227:230]).all()
    assert band[225] == pytest.approx(21.333, abs=0.01)


def test_a_pixel_an_edge_crosses_is_the_mean_over_its_area() -> None:
    """Row 200's pixel 229 spans u 228.5-229.5 and the box starts at u = 229.2 against the sky.

    Of its 3 x 3 rays (u = 228.67, 229, 229.33) one column meets the box, so the pixel is a third
    box; one ray per pixel (at u = 229) makes it all sky. The truth is the centre rays' either way.
    """
    world = _one_box_world()
    point = Renderer(world, Rig(samples=1)).render(0.0, np.random.default_rng(0))
    area = Renderer(world, Rig(samples=3)).render(0.0, np.random.default_rng(0))
    for out, box_share in ((point, 0.0), (area, 1.0 / 3.0)):
        sky, pixel, box = (float(out.left[200, u, 1]) for u in (228, 229, 230))  # green: sky 210, box ~50
        assert (sky - pixel) / (sky - box) == pytest.approx(box_share, abs=0.05)
    assert np.array_equal(point.disparity, area.disparity, equal_nan=True)
    assert np.array_equal(point.object_ids, area.object_ids)
    interior = (slice(160, 230), slice(235, 285))  # the box's face, well inside its edges
    assert np.array_equal(point.left[interior], area.left[interior])
    with pytest.raises(ConfigError, match="odd"):
        Renderer(world, Rig(samples=2))


def test_visible_fraction_counts_the_part_outside_the_image() -> None:
    """A box cut by the left border: its share visible equals what a wider camera sees of it."""
    world = _one_box_world(left=5.333)  # front face from u = -30 to 30, side face to u = 56
    narrow = Renderer(world, Rig()).render(0.0, np.random.default_rng(0))
    wide = Renderer(world, Rig(width=1280)).render(0.0, np.random.default_rng(0))  # same rays, 320 px more each side
    whole = wide.visible_pixels[1]
    assert wide.visible_fraction[1] == pytest.approx(1.0, abs=0.02)
    assert 0.4 < narrow.visible_pixels[1] / whole < 0.8
    assert narrow.visible_fraction[1] == pytest.approx(narrow.visible_pixels[1] / whole, abs=0.02)


@pytest.mark.timeout(120)
def test_truth_disparity_agrees_with_block_matching_where_textured() -> None:
    fm = next(iter(frame_messages("urban", 1, seed=1, image_format="raw")))
    left = cv2.cvtColor(fm.stereo.left, cv2.COLOR_RGB2GRAY)
    right = cv2.cvtColor(fm.stereo.right, cv2.COLOR_RGB2GRAY)
    sgbm = cv2.StereoSGBM.create(minDisparity=0, numDisparities=128, blockSize=5, P1=8 * 25, P2=32 * 25,
                                 uniquenessRatio=10, disp12MaxDiff=1, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    estimate = sgbm.compute(left, right).astype(np.float32) / 16.0
    truth = fm.disparity.disparity
    texture = cv2.blur(np.abs(cv2.Sobel(left, cv2.CV_32F, 1, 0)), (7, 7))
    usable = np.isfinite(truth) & (estimate > 0) & (texture > 8.0)
    assert usable.mean() > 0.3, "too little textured, matched area to judge"
    within = np.abs(estimate[usable] - truth[usable]) <= 1.0
    assert within.mean() > 0.9, f"only {within.mean():.1%} within 1 px"


def test_same_scenario_and_seed_give_identical_bytes(tmp_path: Path) -> None:
    a = simulate_to_file("hanging", tmp_path / "a.mcap", frames=2, seed=7, size=(320, 240))
    b = simulate_to_file("hanging", tmp_path / "b.mcap", frames=2, seed=7, size=(320, 240))
    c = simulate_to_file("hanging", tmp_path / "c.mcap", frames=2, seed=8, size=(320, 240))
    assert a.read_bytes() == b.read_bytes()
    assert a.read_bytes() != c.read_bytes()


@pytest.mark.timeout(120)
@pytest.mark.parametrize("name", list(SCENARIOS))
def test_every_scenario_renders_with_ground_truth(name: str, tmp_path: Path) -> None:
    out = simulate_to_file(name, tmp_path / f"{name}.mcap", frames=2, seed=3, size=(320, 240), image_format="jpeg")
    rec = open_recording(out)
    info = rec.info()
    assert info["source"] == "synthetic" and info["scenario"] == name and info["gt_complete"] is True
    assert info["frames"] == 2 and info["calib"]["width"] == 320
    frames = rec.by_topic("camera/stereo")
    assert sorted(frames) == [0, 1]
    frame = frames[1]
    assert isinstance(frame, StereoFrame) and frame.left.shape == (240, 320, 3)
    assert frame.stamp_ns - frames[0].stamp_ns == 100_000_000
    disparity = rec.by_topic("groundtruth/disparity")[1]
    assert isinstance(disparity, GroundTruthDisparity) and disparity.disparity.shape == (240, 320)
    assert 0.3 < np.isfinite(disparity.disparity).mean() < 1.0
    objects = rec.by_topic("groundtruth/objects")[1]
    assert isinstance(objects, GroundTruthObjects) and objects.gt_complete
    visible = [o for o in objects.objects if o.visible_pixels >= 50 and o.visible_fraction >= 0.5]
    assert len(visible) >= 3
    pose = rec.by_topic("groundtruth/ego")[0].pose
    np.testing.assert_allclose(pose, np.eye(4), atol=1e-9)


def test_a_walker_gathers_speed_at_its_rate_and_still_covers_its_crossing() -> None:
    def speed(path: RoadPath, t: float, eps: float = 1e-4) -> float:
        return (path.road_at(t + eps)[1] - path.road_at(t - eps)[1]) / (2 * eps)

    walk = RoadPath(0.0, 0.0, vd=1.5, t_start=1.0, t_end=1.0 + 9.0 / 1.5 + 1.0, accel=1.5)
    assert walk.road_at(0.5)[1] == 0.0 and walk.road_at(1.0)[1] == 0.0
    assert [round(speed(walk, t), 3) for t in (1.5, 2.0, 4.0, 7.5)] == [0.75, 1.5, 1.5, 0.75]
    assert walk.road_at(8.0)[1] == pytest.approx(9.0) and walk.road_at(9.0)[1] == pytest.approx(9.0)
    short = RoadPath(0.0, 0.0, vd=1.5, t_start=1.0, t_end=2.0, accel=1.5)  # turns back before full speed
    assert speed(short, 1.5) == pytest.approx(0.75, abs=1e-3) and short.road_at(2.0)[1] == pytest.approx(0.375)
    instant = RoadPath(0.0, 0.0, vd=1.5, t_start=1.0, t_end=7.0)
    assert speed(instant, 1.05) == pytest.approx(1.5) and instant.road_at(7.0)[1] == pytest.approx(9.0)
    already = RoadPath(0.0, 0.0, vd=1.5, t_end=5.0, accel=1.5)  # moving when the recording starts
    assert speed(already, 0.5) == pytest.approx(1.5) and speed(already, 4.5) == pytest.approx(0.75, abs=1e-3)


@pytest.mark.parametrize("name", list(SCENARIOS))
@pytest.mark.parametrize("seed", [0, 5])
def test_moving_objects_stay_in_the_volume_at_clear_speeds(name: str, seed: int) -> None:
    """Clear speeds, except while a walker sets off or stops: then the speed ramps at its rate."""
    world = build(name, seed)
    frames_with_movers = 0
    for k in range(10, 100, 5):
        t = k / 10
        to_vehicle = invert(world.ego_pose(t))
        movers = 0
        for st in world.states(t):
            speed = float(np.linalg.norm(st.velocity))
            path = st.thing.path
            full = math.hypot(path.vs, path.vd)
            ramp = path.accel * min(t - path.t_start, path.t_end - t)  # inf without a ramp
            if st.moving and ramp < full:  # in road coordinates: a curve changes the speed a little
                assert full >= 1.25 and speed == pytest.approx(ramp, rel=0.1), st.thing
            elif st.moving:
                assert speed >= 1.25, st.thing
            else:
                assert speed == 0.0, st.thing
            x, y, z = to_vehicle[:3, :3] @ st.center + to_vehicle[:3, 3]
            if st.moving and 0 <= x <= 28.7 and abs(y) <= 8.2 and 0 <= z <= 3.5:
                movers += 1
        frames_with_movers += movers >= 1
    assert frames_with_movers >= 15, f"{name}: moving objects in the volume in only {frames_with_movers}/18 frames"


def test_unknown_scenario_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ConfigError, match="valid: urban, crossing"):
        simulate_to_file("moon", tmp_path / "x.mcap", frames=1, seed=0)
    assert cli_main(["simulate", "moon", "--out", str(tmp_path / "x.mcap")]) == 2
    assert "urban" in capsys.readouterr().err
    assert not (tmp_path / "x.mcap").exists()


def _footprint(center: np.ndarray, rotation: np.ndarray, length: float, width: float) -> np.ndarray:
    signs = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], float)
    return center + (signs * [length / 2, width / 2]) @ rotation.T


def _overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Separating-axis test of two convex quadrilaterals (corners in order)."""
    for poly in (a, b):
        for i in range(4):
            edge = poly[(i + 1) % 4] - poly[i]
            normal = np.array([-edge[1], edge[0]])
            pa, pb = a @ normal, b @ normal
            if pa.max() < pb.min() or pb.max() < pa.min():
                return False
    return True


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_ego_never_drives_through_an_object(name: str) -> None:
    """Traffic and walkers are timed around the ego; only overhead structures may span its path."""
    world = build(name, seed=2)
    for k in range(0, 150, 3):
        t = k / 10
        ego = world.ego_pose(t)
        ego_box = _footprint(ego[:2, 3] + ego[:2, :2] @ [1.5, -0.25], ego[:2, :2], 4.4, 1.8)
        for st in world.states(t):
            if st.thing.cls in ("sign", "barrier"):
                continue
            box = _footprint(st.pose[:2, 3], st.pose[:2, :2], st.thing.size[0], st.thing.size[1])
            assert not _overlap(ego_box, box), f"frame {k}: ego overlaps {st.thing.cls} {st.thing.id}"


def test_the_clearance_check_finds_bodies_that_meet_and_passes_those_beneath_a_beam() -> None:
    road = Road(y0=0.0)
    clothes = (0.5, 0.2, 0.2)
    things = (
        box(1, "kiosk", RoadPath(-40.0, 7.5), (3.0, 1.8, 2.6), clothes),
        box(2, "bin", RoadPath(-39.5, 7.0), (0.6, 0.6, 1.0), clothes),  # inside the kiosk
        pedestrian(3, RoadPath(20.0, 7.2, vs=1.5), clothes, clothes),
        pedestrian(4, RoadPath(30.0, 7.3, vs=-1.5, yaw=math.pi), clothes, clothes),  # meets 3 after 3.3 s
        pedestrian(5, RoadPath(40.0, 7.9, vs=-1.5, yaw=math.pi), clothes, clothes),  # a lane further: passes
        gantry(6, RoadPath(60.0, 0.0), 13.0, 2.8, clothes),
        pedestrian(7, RoadPath(55.0, 0.0, vs=1.5), clothes, clothes),  # under the beam: free space
        pedestrian(8, RoadPath(55.0, 6.5, vs=1.5), clothes, clothes),  # into the post at d = 6.5
    )
    found = {(a, b): t for t, a, b in shared_volume(road, things)}
    assert set(found) == {(1, 2), (3, 4), (6, 8)}
    assert found[(1, 2)] == 0.0
    assert found[(3, 4)] == pytest.approx((10.0 - 0.32) / 3.0, abs=0.06)
    assert found[(6, 8)] == pytest.approx((5.0 - 0.125 - 0.16) / 1.5, abs=0.06)


def test_walkers_in_a_lane_never_reach_the_one_ahead() -> None:
    movers = [(0.0, 1.9), (8.0, 1.4), (20.0, -1.5), (30.0, -1.8), (12.0, 0.0)]
    speeds = keep_pace(movers, gap=1.0, horizon=30.0)
    assert speeds[1] == 1.4 and speeds[2] == -1.5 and speeds[4] == 0.0
    assert speeds[0] == pytest.approx(1.4 + 7.0 / 30.0)  # caught the slower one ahead at 30 s, not before
    assert speeds[3] == pytest.approx(-(1.5 + 9.0 / 30.0))


@pytest.mark.parametrize("name", list(SCENARIOS))
@pytest.mark.parametrize("seed", [0, 7, 11])
def test_no_two_bodies_ever_share_volume(name: str, seed: int) -> None:
    """Bins outside kiosks, walkers past each other and the poles, cars clear of the fences."""
    world = build(name, seed)
    clashes = shared_volume(world.road, world.things)
    cls = {t.id: t.cls for t in world.things}
    assert not clashes, [(t, cls[a], a, cls[b], b) for t, a, b in clashes[:5]]


@pytest.mark.parametrize("name", ["urban", "crossing"])
def test_no_two_bodies_share_volume_where_the_world_puts_them(name: str) -> None:
    """The same, from the poses the renderer uses and this file's own separating-axis test."""
    world = build(name, seed=7)
    solid = [t for t in world.things if t.cls not in OPEN_CLASSES]
    for k in range(0, 150, 5):
        states = [world.state(t, k / 10) for t in solid]
        boxes = [_footprint(st.pose[:2, 3], st.pose[:2, :2], st.thing.size[0], st.thing.size[1]) for st in states]
        centres = np.array([b.mean(axis=0) for b in boxes])
        reach = np.array([math.hypot(*st.thing.size[:2]) / 2 for st in states])
        near = np.linalg.norm(centres[:, None] - centres[None], axis=-1) < reach[:, None] + reach[None]
        for i, j in zip(*np.nonzero(np.triu(near, 1)), strict=True):
            where = f"{k / 10} s: {solid[i].cls} {solid[i].id} in {solid[j].cls} {solid[j].id}"
            assert not _overlap(boxes[i], boxes[j]), where


def test_bundled_recording_is_the_documented_one() -> None:
    """recordings/README.md: 64 urban frames, seed 1, under the 15 MB the repository allows."""
    path = Path(__file__).resolve().parents[1] / "recordings" / "urban.mcap"
    assert path.stat().st_size < 15e6
    reader = open_recording(path)
    info = reader.info()
    assert (info["scenario"], info["seed"], info["frames"], info["gt_complete"]) == ("urban", 1, 64, True)
    assert sorted(reader.by_topic("groundtruth/ego")) == list(range(64))
