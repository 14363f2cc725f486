"""Importers on the shared KITTI and Middlebury samples: counts, frames of reference, ground truth, bad input."""

from __future__ import annotations

import itertools
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_path

from common.datasets import kitti_odometry, kitti_raw, kitti_tracking, middlebury, velodyne
from common.errors import InputError
from common.evaluation.odometry import load_kitti_poses, odometry_errors
from common.messages import GroundTruthDisparity, GroundTruthEgo, GroundTruthObjects, StereoFrame
from common.recording import open_recording
from services.cli import main as cli_main
from services.pipeline import config_for

DATE = ("data", "kitti_raw", "2011_09_26")
DRIVE = (*DATE, "2011_09_26_drive_0009_sync")
TRAINING = ("data", "kitti_tracking", "training")
ODOMETRY = ("data", "kitti_odometry", "dataset")


def by_type(path: Path) -> dict[type, dict[int, object]]:
    out: dict[type, dict[int, object]] = {}
    for _, msg in open_recording(path).messages():
        out.setdefault(type(msg), {})[msg.frame_id] = msg
    return out


def calib_rows(path: Path) -> dict[str, np.ndarray]:
    """An independent reading of a KITTI calibration file: every all-numeric line, by key."""
    rows = {}
    for line in path.read_text().splitlines():
        key, _, rest = line.partition(":")
        try:
            rows[key.strip()] = np.array(rest.split(), dtype=float)
        except ValueError:
            continue
    return rows


# ----------------------------------------------------------------------------- KITTI raw


@pytest.mark.timeout(60)
def test_raw_import_frames_pose_lidar_and_info(tmp_path: Path) -> None:
    out = tmp_path / "raw.mcap"
    assert kitti_raw.import_drive(shared_path(*DRIVE), out, max_frames=3) == 3
    msgs = by_type(out)
    assert sorted(msgs[StereoFrame]) == [0, 1, 2]
    frame = msgs[StereoFrame][0]
    assert frame.left.shape == (375, 1242, 3) and frame.image_format == "png"
    assert frame.calib.baseline == pytest.approx((44.857 + 339.524) / 721.5377, abs=1e-3)
    assert np.allclose(msgs[GroundTruthEgo][0].pose, np.eye(4))
    assert 0.9 < msgs[GroundTruthEgo][2].pose[0, 3] < 2.5  # ~10.5 m/s forward over 0.2 s
    assert sorted(msgs[GroundTruthDisparity]) == [0]  # scans exist for frames 0, 25, 50
    assert msgs[GroundTruthDisparity][0].sparse
    reader = open_recording(out)
    info = reader.info()
    assert info["source"] == "kitti-raw" and info["gt_complete"] is False and info["frames"] == 3
    assert reader.config_dict() is not None and "voxel" in reader.config_dict()  # the effective configuration
    cfg = config_for(reader)  # what `process` runs with: the rig's disparity bias and KITTI's volume
    assert (cfg.odometry.disparity_offset_px, cfg.odometry.disparity_edge_px, cfg.volume.x_max) == (0.16, 1.3, 45.0)
    assert (cfg.stereo.disparity_offset_px, cfg.stereo.disparity_edge_px) == (0.16, 1.3)  # the points' depths too
    assert config_for(reader, sets=["odometry.disparity_offset_px=0"]).odometry.disparity_offset_px == 0.0
    assert info["volume"] == {
        "x_min": 0.0, "x_max": 45.0, "y_half": 10.0, "z_min": 0.0, "z_max": 3.5, "lookahead_m": 1.5
    }  # fmt: skip
    assert np.allclose(info["calib"]["cam_to_vehicle"], [[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 1.65], [0, 0, 0, 1]])
    stamps = [msgs[StereoFrame][k].stamp_ns for k in range(3)]
    assert all(0.09e9 < b - a < 0.11e9 for a, b in itertools.pairwise(stamps))


def test_velodyne_points_land_at_the_disparity_their_depth_predicts() -> None:
    date = shared_path(*DATE)
    seq = kitti_raw.load(shared_path(*DRIVE), max_frames=1)
    scan = velodyne.read_scan(shared_path(*DRIVE, "velodyne_points", "data", "0000000000.bin"))
    from common.datasets.kitti_calib import load_raw

    truth = velodyne.scan_disparity(scan, load_raw(date).velo_to_cam2(), seq.calib)
    # the same points through the published projection P_rect_02 . R_rect_00 . Tr_velo_to_cam
    cam = calib_rows(date / "calib_cam_to_cam.txt")
    velo = calib_rows(date / "calib_velo_to_cam.txt")
    p2, rect, tr = cam["P_rect_02"].reshape(3, 4), np.eye(4), np.eye(4)
    rect[:3, :3] = cam["R_rect_00"].reshape(3, 3)
    tr[:3, :3], tr[:3, 3] = velo["R"].reshape(3, 3), velo["T"]
    fx, baseline = p2[0, 0], (p2[0, 3] - cam["P_rect_03"].reshape(3, 4)[0, 3]) / p2[0, 0]
    homogeneous = np.c_[scan[:, :3], np.ones(len(scan))] @ (p2 @ rect @ tr).T
    front = homogeneous[:, 2] > 0
    u = np.rint(homogeneous[front, 0] / homogeneous[front, 2]).astype(int)
    v = np.rint(homogeneous[front, 1] / homogeneous[front, 2]).astype(int)
    depth = homogeneous[front, 2]
    inside = (u >= 0) & (u < 1242) & (v >= 0) & (v < 375)
    nearest = np.full((375, 1242), np.inf)
    np.minimum.at(nearest, (v[inside], u[inside]), depth[inside])
    expected = np.where(np.isfinite(nearest), fx * baseline / nearest, np.nan)
    assert np.array_equal(np.isfinite(truth), np.isfinite(expected))
    assert 10_000 < np.isfinite(truth).sum() < 30_000
    assert np.nanmax(np.abs(truth - expected)) < 1.0
    # a single point: its disparity where it lands, unless a nearer point owns the pixel
    k = int(np.argmax(depth[inside] < 20.0))
    pu, pv, pd = u[inside][k], v[inside][k], depth[inside][k]
    assert truth[pv, pu] >= fx * baseline / pd - 1.0


def test_raw_oxts_truth_reproduces_the_viso2_anchor_and_its_speed_integrates() -> None:
    seq = kitti_raw.load(shared_path(*DRIVE))
    assert len(seq.frames) == 51 and seq.poses is not None and seq.velocities is not None
    assert np.allclose(seq.poses[0], np.eye(4))
    c = seq.calib.cam_to_vehicle
    truth_cam2 = [np.linalg.inv(c) @ p @ c for p in seq.poses]
    est = load_kitti_poses(str(shared_path("anchors", "viso2_raw0009_poses.txt")))
    errors = odometry_errors(est, truth_cam2)
    assert errors is not None and errors["t_err_pct"] == pytest.approx(3.34, abs=0.05)
    times = np.array(seq.stamps) / 1e9
    speeds = np.linalg.norm(seq.velocities, axis=1)
    travelled = float(np.sum(0.5 * (speeds[1:] + speeds[:-1]) * np.diff(times)))
    distance = float(np.linalg.norm(seq.poses[-1][:3, 3]))
    assert travelled == pytest.approx(distance, rel=0.02)
    assert seq.poses[-1][0, 3] > 50.0  # forward is +x


# ----------------------------------------------------------------------------- KITTI tracking


def test_tracking_labels_one_mover_and_the_van_in_the_ignored_band() -> None:
    loaded = kitti_tracking.load(shared_path(*TRAINING), "0001")
    assert sorted(loaded.truth) == list(range(51))
    speeds: dict[int, list[float]] = {}
    for msg in loaded.truth.values():
        for obj in msg.objects:
            speeds.setdefault(obj.id, []).append(float(np.linalg.norm(obj.velocity)))
            assert obj.moving == (np.linalg.norm(obj.velocity) >= 1.0)
    movers = {track for track, s in speeds.items() if max(s) >= 1.0}
    assert movers == {8}
    frames_of_8 = [f for f, msg in loaded.truth.items() if any(o.id == 8 for o in msg.objects)]
    assert frames_of_8 == list(range(35, 51))
    assert 5.0 < np.median(speeds[8]) < 8.0
    assert 0.3 <= np.median(speeds[89]) < 1.0
    car8 = next(o for o in loaded.truth[45].objects if o.id == 8)
    assert car8.velocity[0] < -4.0  # oncoming: against the ego's +x in the world


def test_tracking_boxes_stand_on_the_road_in_the_vehicle_frame() -> None:
    loaded = kitti_tracking.load(shared_path(*TRAINING), "0001", max_frames=1)
    objects = loaded.truth[0].objects
    assert objects and np.allclose(loaded.sequence.poses[0], np.eye(4))
    for obj in objects:  # frame 0: world = vehicle frame; ahead of the car, near ones standing on the road
        assert obj.center[0] > 0.0
        if obj.center[0] < 20.0:  # farther, the street's slope and camber lift or drop them by up to ~0.8 m
            assert obj.center[2] - obj.size[2] / 2.0 == pytest.approx(0.0, abs=0.3)
        assert obj.size[0] > obj.size[1]  # (length, width, height)
        assert obj.truncated >= 0.0 and obj.occluded >= 0
    parked_ahead_right = [o for o in objects if o.cls == "Car" and o.center[1] < 0]
    assert parked_ahead_right and all(abs(np.cos(o.yaw)) > 0.9 for o in parked_ahead_right)  # along the street
    assert loaded.truth[0].dontcare.shape[1] == 4 and len(loaded.truth[0].dontcare) > 0


@pytest.mark.timeout(60)
def test_tracking_import_writes_objects_and_dontcare(tmp_path: Path) -> None:
    out = tmp_path / "trk.mcap"
    assert cli_main(["import", "kitti-tracking", str(shared_path(*TRAINING)), "--sequence", "0001",
                     "--out", str(out), "--max-frames", "2"]) == 0
    msgs = by_type(out)
    assert sorted(msgs[StereoFrame]) == [0, 1] and sorted(msgs[GroundTruthObjects]) == [0, 1]
    truth: GroundTruthObjects = msgs[GroundTruthObjects][1]  # type: ignore[assignment]
    assert len(truth.objects) >= 6 and truth.dontcare.shape == (len(truth.dontcare), 4) and len(truth.dontcare)
    assert open_recording(out).info()["source"] == "kitti-tracking"


# ----------------------------------------------------------------------------- odometry, Middlebury


def test_odometry_poses_reproduce_the_viso2_anchor() -> None:
    root = shared_path(*ODOMETRY)
    seq = kitti_odometry.load(root / "sequences" / "04", root / "poses" / "04.txt")
    assert len(seq.frames) == 40 and seq.poses is not None
    assert np.allclose(seq.poses[0], np.eye(4))
    assert seq.poses[-1][0, 3] == pytest.approx(53.5, abs=1.0)
    c = seq.calib.cam_to_vehicle
    est = load_kitti_poses(str(shared_path("anchors", "viso2_odo04_poses.txt")))
    errors = odometry_errors(est, [np.linalg.inv(c) @ p @ c for p in seq.poses])
    assert errors is not None and errors["t_err_pct"] == pytest.approx(1.68, abs=0.05)


def test_middlebury_scenes_carry_quarter_scale_truth(tmp_path: Path) -> None:
    out = tmp_path / "mb.mcap"
    assert middlebury.import_scenes(shared_path("data", "middlebury"), out) == 2
    msgs = by_type(out)
    cones: GroundTruthDisparity = msgs[GroundTruthDisparity][0]  # type: ignore[assignment]
    assert not cones.sparse and cones.disparity.shape == (375, 450)
    assert np.nanmax(cones.disparity) == pytest.approx(220 / 4)
    assert 0.01 < np.isnan(cones.disparity).mean() < 0.06  # ~3 % unknown
    info = open_recording(out).info()
    assert info["source"] == "middlebury" and info["scenes"] == ["cones", "teddy"] and "volume" not in info
    calib = msgs[StereoFrame][0].calib
    assert calib.fx * calib.baseline / 2.0 > np.nanmax(cones.disparity)  # the automatic search range reaches it


# ----------------------------------------------------------------------------- bad input


@pytest.fixture
def small_training(tmp_path: Path) -> Path:
    """Tracking sequence 0001 cut to three frames, in a folder the test may break."""
    src = shared_path(*TRAINING)
    dst = tmp_path / "training"
    for cam in ("image_02", "image_03"):
        (dst / cam / "0001").mkdir(parents=True)
        for k in range(3):
            shutil.copy(src / cam / "0001" / f"{k:06d}.png", dst / cam / "0001")
    for part in ("calib", "oxts", "label_02"):
        (dst / part).mkdir()
        shutil.copy(src / part / "0001.txt", dst / part)
    return dst


def import_fails(training: Path, out: Path) -> str:
    with pytest.raises(InputError) as err:
        kitti_tracking.import_sequence(training, "0001", out)
    assert not out.exists() and not out.with_name(out.name + ".part").exists()
    return str(err.value)


def test_missing_calibration_is_named(small_training: Path, tmp_path: Path) -> None:
    (small_training / "calib" / "0001.txt").unlink()
    assert "calib/0001.txt: calibration file missing" in import_fails(small_training, tmp_path / "o.mcap")


def test_malformed_oxts_line_is_named(small_training: Path, tmp_path: Path) -> None:
    path = small_training / "oxts" / "0001.txt"
    lines = path.read_text().splitlines()
    lines[1] = lines[1].replace("8.43", "8,43", 1)
    path.write_text("\n".join(lines) + "\n")
    assert "oxts/0001.txt:2: OXTS packet" in import_fails(small_training, tmp_path / "o.mcap")


def test_mismatched_frame_counts_are_refused(small_training: Path, tmp_path: Path) -> None:
    (small_training / "image_03" / "0001" / "000002.png").unlink()
    message = import_fails(small_training, tmp_path / "o.mcap")
    assert "has 3 images" in message and "has 2" in message


def test_unreadable_png_midway_leaves_no_recording(small_training: Path, tmp_path: Path) -> None:
    (small_training / "image_03" / "0001" / "000002.png").write_bytes(b"\x89PNG not really")
    assert "000002.png: not a readable image" in import_fails(small_training, tmp_path / "o.mcap")


def test_cli_exits_2_naming_the_file(small_training: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    calib = small_training / "calib" / "0001.txt"
    lines = calib.read_text().splitlines()
    calib.write_text("\n".join("P2: 1 2 3" if line.startswith("P2:") else line for line in lines))
    out = tmp_path / "o.mcap"
    assert cli_main(["import", "kitti-tracking", str(small_training), "--sequence", "0001", "--out", str(out)]) == 2
    assert "calib/0001.txt:3: P2 needs 12 finite numbers, has 3" in capsys.readouterr().err
    assert not out.exists()


# ----------------------------------------------------------------------------- raw: tracklets, per-file OXTS

TRACKLET_XML = """<?xml version="1.0" encoding="UTF-8" standalone="yes" ?>
<!DOCTYPE boost_serialization>
<boost_serialization signature="serialization::archive" version="9">
<tracklets class_id="0" tracking_level="0" version="0">
  <count>2</count>
  <item_version>1</item_version>
  <item class_id="1" tracking_level="0" version="1">
    <objectType>Car</objectType><h>1.5</h><w>1.6</w><l>4.0</l><first_frame>0</first_frame>
    <poses class_id="2" tracking_level="0" version="0"><count>2</count><item_version>2</item_version>
      <item class_id="3" tracking_level="0" version="2"><tx>10.0</tx><ty>-3.0</ty><tz>-1.73</tz>
        <rx>0</rx><ry>0</ry><rz>0.0</rz><state>1</state><occlusion>0</occlusion><occlusion_kf>0</occlusion_kf>
        <truncation>0</truncation><amt_occlusion>-1</amt_occlusion><amt_occlusion_kf>-1</amt_occlusion_kf>
        <amt_border_l>-1</amt_border_l><amt_border_r>-1</amt_border_r><amt_border_kf>-1</amt_border_kf></item>
      <item><tx>9.0</tx><ty>-3.0</ty><tz>-1.73</tz><rx>0</rx><ry>0</ry><rz>0.0</rz><state>1</state>
        <occlusion>1</occlusion><occlusion_kf>0</occlusion_kf><truncation>0</truncation></item>
    </poses><finished>1</finished>
  </item>
  <item>
    <objectType>Pedestrian</objectType><h>1.8</h><w>0.6</w><l>0.8</l><first_frame>1</first_frame>
    <poses><count>1</count><item_version>2</item_version>
      <item><tx>6.0</tx><ty>4.0</ty><tz>-1.73</tz><rx>0</rx><ry>0</ry><rz>1.5708</rz><state>1</state>
        <occlusion>-1</occlusion><occlusion_kf>0</occlusion_kf><truncation>1</truncation></item>
    </poses><finished>1</finished>
  </item>
</tracklets>
</boost_serialization>
"""


@pytest.fixture
def small_drive(tmp_path: Path) -> Path:
    """Raw drive 0009 cut to two frames (no Velodyne), in a folder the test may change."""
    src_date, src = shared_path(*DATE), shared_path(*DRIVE)
    date = tmp_path / "2011_09_26"
    drive = date / src.name
    for name in ("calib_cam_to_cam.txt", "calib_velo_to_cam.txt", "calib_imu_to_velo.txt"):
        date.mkdir(exist_ok=True)
        shutil.copy(src_date / name, date)
    for part in ("image_02/data", "image_03/data", "oxts/data"):
        (drive / part).mkdir(parents=True)
        suffix = ".txt" if part.startswith("oxts") else ".png"
        for k in range(2):
            shutil.copy(src / part / f"{k:010d}{suffix}", drive / part)
    shutil.copy(src / "image_02" / "timestamps.txt", drive / "image_02")
    return drive


def test_raw_tracklets_become_world_objects(small_drive: Path, tmp_path: Path) -> None:
    (small_drive / "tracklet_labels.xml").write_text(TRACKLET_XML)
    out = tmp_path / "raw.mcap"
    assert kitti_raw.import_drive(small_drive, out) == 2
    truth = by_type(out)[GroundTruthObjects]
    car = next(o for o in truth[0].objects if o.cls == "Car")
    # independently: Velodyne -> camera 0 -> rectified -> cam2 (x shifted by P2's offset) -> vehicle axes
    date = small_drive.parent
    cam, velo = calib_rows(date / "calib_cam_to_cam.txt"), calib_rows(date / "calib_velo_to_cam.txt")
    p2 = cam["P_rect_02"].reshape(3, 4)
    point = velo["R"].reshape(3, 3) @ np.array([10.0, -3.0, -1.73 + 0.75]) + velo["T"]
    point = cam["R_rect_00"].reshape(3, 3) @ point + np.linalg.solve(p2[:, :3], p2[:, 3])
    expected = np.array([point[2], -point[0], 1.65 - point[1]])
    assert np.allclose(car.center, expected, atol=1e-6)
    assert car.center[2] == pytest.approx(0.75, abs=0.15)  # the Velodyne sits ~1.73 m above the road
    assert car.size.tolist() == [4.0, 1.6, 1.5] and abs(car.yaw) < 0.05
    assert (car.truncated, car.occluded) == (0.0, 0)
    walker = next(o for o in truth[1].objects if o.cls == "Pedestrian")
    assert (walker.truncated, walker.occluded) == (1.0, -1) and walker.yaw == pytest.approx(np.pi / 2, abs=0.05)
    assert [o.occluded for o in truth[1].objects if o.cls == "Car"] == [1]


def test_raw_malformed_oxts_packet_is_named(small_drive: Path, tmp_path: Path) -> None:
    packet = small_drive / "oxts" / "data" / "0000000001.txt"
    packet.write_text(" ".join(packet.read_text().split()[:20]))
    out = tmp_path / "raw.mcap"
    with pytest.raises(InputError, match=r"0000000001.txt:1: OXTS packet needs 30 finite numbers, has 20"):
        kitti_raw.import_drive(small_drive, out)
    assert not out.exists()


@pytest.mark.timeout(60)
def test_tracking_velodyne_truth_matches_the_raw_drive(small_training: Path, tmp_path: Path) -> None:
    """Tracking 0001 is raw drive 0009: a scan in the tracking layout gives the raw import's truth."""
    (small_training / "velodyne" / "0001").mkdir(parents=True)
    shutil.copy(shared_path(*DRIVE, "velodyne_points", "data", "0000000000.bin"),
                small_training / "velodyne" / "0001" / "000000.bin")
    tracking_out, raw_out = tmp_path / "trk.mcap", tmp_path / "raw.mcap"
    kitti_tracking.import_sequence(small_training, "0001", tracking_out, max_frames=1)
    kitti_raw.import_drive(shared_path(*DRIVE), raw_out, max_frames=1)
    tracking = by_type(tracking_out)[GroundTruthDisparity][0].disparity
    raw = by_type(raw_out)[GroundTruthDisparity][0].disparity
    assert np.array_equal(np.isfinite(tracking), np.isfinite(raw))
    assert np.nanmax(np.abs(tracking - raw)) < 0.01  # the tracking calibration rounds the same numbers
    assert open_recording(tracking_out).info()["lidar_frames"] == [0]
