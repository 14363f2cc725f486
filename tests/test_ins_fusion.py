"""The vehicle's motion sensors (vehicle/motion) in the odometry: fusion, bridging, import, graph, bus."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO, shared_path, stereovox_cmd
from test_deploy import _check, _spec_variant
from test_odometry import cam_motion, frame, vehicle_pose

from common.config import Config
from common.config_loading import load_config
from common.datasets import kitti_raw
from common.errors import ConfigError
from common.messages import GroundTruthEgo, StereoFrame, VehicleMotion
from common.recording import RecordingWriter, open_recording
from services.demo import BUNDLED
from services.odometry import StereoOdometry
from services.odometry.ins import SensorNoise, fuse_step, sensor_step, yaw_of
from services.pipeline import process_file

DRIVE = ("data", "kitti_raw", "2011_09_26", "2011_09_26_drive_0009_sync")
DT = 0.1  # the test frames are 100 ms apart


def sample(i: int, speed: float, yaw_rate: float) -> VehicleMotion:
    return VehicleMotion(frame_id=i, stamp_ns=i * 100_000_000, speed_mps=speed, yaw_rate_rps=yaw_rate)


def fusing(**values: float) -> StereoOdometry:
    sets = ["odometry.fuse_ins=true", *(f"odometry.{k}={v}" for k, v in values.items())]
    return StereoOdometry.from_config(load_config(None, sets))


def test_fused_step_is_the_inverse_variance_mean_along_the_vision_direction() -> None:
    step = np.eye(4)
    step[0:3, 3] = [1.1, 0.05, 0.0]  # vision: 1.1 m, slightly left
    cov = np.zeros((6, 6))
    vehicle = sample(1, speed=10.0, yaw_rate=np.radians(2.0))  # sensors: 1.0 m and 0.2 deg
    noise = SensorNoise(
        speed_mps=0.05, yaw_rate_rps=np.radians(0.5), vision_scale=0.01, vision_yaw_per_m=np.radians(0.5)
    )
    fused, fused_cov = fuse_step(step, cov, vehicle, DT, noise)
    length = float(np.linalg.norm(step[0:3, 3]))
    var_vision, var_sensor = (0.01 * length) ** 2, (0.05 * DT) ** 2
    half_turn = 0.5 * np.radians(0.2)
    chord = 1.0 * np.sin(half_turn) / half_turn
    expected = (length * var_sensor + chord * var_vision) / (var_vision + var_sensor)
    assert np.linalg.norm(fused[0:3, 3]) == pytest.approx(expected, rel=1e-9)
    assert 1.0 < expected < 1.05  # closer to the sensors: they are the surer of the two here
    assert np.allclose(fused[0:3, 3] / expected, step[0:3, 3] / length)  # the direction stays the vision's
    yaw_var_vision, yaw_var_sensor = (np.radians(0.5) * length) ** 2, (np.radians(0.5) * DT) ** 2
    expected_yaw = np.radians(0.2) * yaw_var_vision / (yaw_var_vision + yaw_var_sensor)
    assert yaw_of(fused) == pytest.approx(expected_yaw, rel=1e-9)
    assert fused_cov[5, 5] == pytest.approx(yaw_var_vision * yaw_var_sensor / (yaw_var_vision + yaw_var_sensor))
    along = fused[0:3, 3] / expected
    assert along @ fused_cov[0:3, 0:3] @ along == pytest.approx(var_vision * var_sensor / (var_vision + var_sensor))
    # sensors with a huge noise leave the vision alone
    vague = SensorNoise(speed_mps=1e3, yaw_rate_rps=1e3, vision_scale=0.01, vision_yaw_per_m=0.01)
    assert np.allclose(fuse_step(step, cov, vehicle, DT, vague)[0], step, atol=1e-6)


def test_sensor_step_is_the_chord_of_the_arc() -> None:
    step = sensor_step(sample(0, speed=10.0, yaw_rate=2.0), DT)  # 1 m along a 0.2 rad left turn
    chord = 2.0 * (1.0 / 0.2) * np.sin(0.1)
    assert yaw_of(step) == pytest.approx(0.2)
    assert np.linalg.norm(step[0:3, 3]) == pytest.approx(chord, rel=1e-12)
    assert np.arctan2(step[1, 3], step[0, 3]) == pytest.approx(0.1)  # it points half the turn to the left
    assert step[2, 3] == 0.0
    straight = sensor_step(sample(0, speed=10.0, yaw_rate=0.0), DT)
    assert np.allclose(straight[0:3, 3], [1.0, 0.0, 0.0]) and np.allclose(straight[0:3, 0:3], np.eye(3))


@pytest.mark.timeout(60)
def test_sensors_shorten_a_step_only_with_fusion_on() -> None:
    """Sensors saying 10 % less than the vision: ignored with fusion off, followed with it on."""
    step = cam_motion(0.0, (0.0, 0.0, 1.0))
    truth_speed = 10.0
    outs: dict[str, list] = {"none": [], "off": [], "on": []}
    odos = {
        "none": StereoOdometry.from_config(Config()),
        "off": StereoOdometry.from_config(Config()),
        "on": fusing(ins_speed_std_mps=0.001),
    }
    for i in range(3):
        f = frame(i, np.linalg.matrix_power(step, i))
        for name, odo in odos.items():
            outs[name].append(odo.process(f, None if name == "none" else sample(i, 0.9 * truth_speed, 0.0)))
    for i in (1, 2):
        assert np.array_equal(outs["off"][i].pose, outs["none"][i].pose)
        assert np.linalg.norm(outs["none"][i].delta[0:3, 3]) == pytest.approx(1.0, abs=0.01)
        assert np.linalg.norm(outs["on"][i].delta[0:3, 3]) == pytest.approx(0.9, abs=0.005)
        assert outs["on"][i].valid


@pytest.mark.timeout(60)
def test_a_black_frame_is_bridged_by_the_sensors() -> None:
    step = cam_motion(0.5, (0.0, 0.0, 0.5))
    vstep = vehicle_pose(step)
    speed, yaw_rate = float(np.linalg.norm(vstep[0:3, 3])) / DT, yaw_of(vstep) / DT
    poses = [np.linalg.matrix_power(step, i) for i in range(5)]
    odo = fusing()
    outs = [odo.process(frame(i, poses[i], black=(i == 2)), sample(i, speed, yaw_rate)) for i in range(5)]
    assert [o.valid for o in outs] == [True, True, False, True, True]
    assert np.allclose(outs[2].delta, sensor_step(sample(2, speed, yaw_rate), DT), atol=1e-12)
    assert np.linalg.norm(outs[2].pose[0:3, 3] - vehicle_pose(poses[2])[0:3, 3]) < 0.01
    assert outs[2].covariance[0, 0] == pytest.approx((0.05 * DT) ** 2)  # the sensors' own uncertainty
    assert np.linalg.norm(outs[4].pose[0:3, 3] - vehicle_pose(poses[4])[0:3, 3]) < 0.02


@pytest.mark.timeout(120)
def test_process_refuses_fusion_without_sensors_in_the_recording(tmp_path: Path) -> None:
    out = tmp_path / "run.mcap"
    with pytest.raises(ConfigError, match=r"odometry.fuse_ins needs vehicle/motion .*urban.mcap has none"):
        process_file(BUNDLED, out, max_frames=2, with_frames=False, sets=["odometry.fuse_ins=true"])
    assert not out.exists() and not list(tmp_path.iterdir())  # nothing half-written left behind


@pytest.fixture(scope="module")
def raw_drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("ins") / "raw.mcap"
    assert kitti_raw.import_drive(shared_path(*DRIVE), out, max_frames=6) == 6
    return out


@pytest.mark.timeout(120)
def test_raw_import_puts_the_ins_before_each_frame(raw_drive: Path) -> None:
    order = [(type(m).__name__, m.frame_id) for _, m in open_recording(raw_drive).messages()
             if isinstance(m, (VehicleMotion, StereoFrame))]
    assert order == [(kind, i) for i in range(6) for kind in ("VehicleMotion", "StereoFrame")]
    sensors = {m.frame_id: m for _, m in open_recording(raw_drive).messages(topics=["vehicle/motion"])}
    truth = {m.frame_id: m for _, m in open_recording(raw_drive).messages(topics=["groundtruth/ego"])}
    for i, s in sensors.items():
        assert isinstance(truth[i], GroundTruthEgo) and s.source == "oxts"
        assert s.speed_mps == pytest.approx(np.linalg.norm(truth[i].velocity), abs=0.1)  # ~10.5 m/s


def test_ins_yaw_rate_turns_the_way_the_oxts_heading_does() -> None:
    """The gyro column and its sign against the heading the true poses come from (the drive bends
    right over frames 36-50)."""
    seq = kitti_raw.load(shared_path(*DRIVE))
    assert seq.motion is not None and seq.poses is not None
    dts = np.diff(seq.stamps) * 1e-9
    gyro = seq.motion[1:, 1] * dts
    steps = [np.linalg.inv(a) @ b for a, b in zip(seq.poses[:-1], seq.poses[1:], strict=True)]
    heading = np.array([yaw_of(step) for step in steps])
    assert np.corrcoef(gyro, heading)[0, 1] > 0.9
    assert gyro[35:].sum() == pytest.approx(heading[35:].sum(), rel=0.1) and heading[35:].sum() < -0.01
    travelled = np.linalg.norm([step[0:3, 3] for step in steps], axis=1)
    assert (seq.motion[1:, 0] * dts).sum() == pytest.approx(travelled.sum(), rel=0.02)


@pytest.mark.timeout(300)
def test_process_pairs_each_frame_with_its_own_sample_wherever_it_lies(raw_drive: Path, tmp_path: Path) -> None:
    """A bus recording may hold a sample after its frame: the pairing is by frame id, not by order."""
    late = tmp_path / "late.mcap"
    reader = open_recording(raw_drive)
    with RecordingWriter(late) as writer:
        writer.describe(reader.config_dict(), reader.info())
        held: tuple[str, VehicleMotion] | None = None
        for key, msg in reader.messages():
            if isinstance(msg, VehicleMotion):
                held = (key, msg)
                continue
            writer.write(key, msg)
            if isinstance(msg, StereoFrame) and held is not None:
                writer.write(*held)  # right after the frame it belongs to
                held = None
    runs = {}
    for name, source in (("in order", raw_drive), ("late", late)):
        runs[name] = tmp_path / f"{name}.mcap"
        process_file(source, runs[name], max_frames=4, with_frames=False, sets=["odometry.fuse_ins=true"])
    first, second = (open_recording(path).by_topic("odometry/ego") for path in runs.values())
    assert sorted(first) == sorted(second) == [0, 1, 2, 3]
    for i in first:
        assert np.array_equal(first[i].pose, second[i].pose), i


def test_demo_refuses_a_fusing_graph_on_a_recording_without_sensors(tmp_path: Path) -> None:
    proc = subprocess.run(
        stereovox_cmd("demo", "--graph", str(REPO / "deploy" / "local-ins.yaml"), "--max-frames", "2",
                      "--out", str(tmp_path)),
        cwd=REPO, capture_output=True, text=True, timeout=60,
    )
    assert proc.returncode == 2
    assert "odometry joins every frame with vehicle/motion" in proc.stderr and "urban.mcap has none" in proc.stderr
    assert not (tmp_path / "logs").exists()  # refused before any process was started


def test_check_wants_the_sensor_input_of_a_fusing_odometry(tmp_path: Path) -> None:
    values = ("port=1", "out=o", "recording=r", "max_frames=1")
    assert _check(REPO / "deploy" / "local-ins.yaml", *values).returncode == 0
    inputs = {"camera/stereo": {"schema": "stereovox.StereoFrame/1", "queue": "fifo"}}
    spec = _spec_variant(tmp_path, "local-ins.yaml", "no-sensor.yaml", {"odometry": {"inputs": inputs}})
    proc = _check(spec, *values)
    assert proc.returncode == 2
    assert "service odometry: the code reads vehicle/motion, the spec does not list it" in proc.stderr


def without_sample(source: Path, out: Path, frame_id: int) -> Path:
    """A copy of a recording whose INS dropped the sample of one frame."""
    reader = open_recording(source)
    with RecordingWriter(out) as writer:
        writer.describe(reader.config_dict(), reader.info())
        for key, msg in reader.messages():
            if not (isinstance(msg, VehicleMotion) and msg.frame_id == frame_id):
                writer.write(key, msg)
    return out


@pytest.mark.timeout(400)
def test_fusing_graph_over_the_bus_matches_process(raw_drive: Path, tmp_path: Path) -> None:
    """deploy/local-ins.yaml: the replay publishes the INS, the odometry joins it with each frame;
    frame 2's sample is missing, and that frame goes on with vision alone on both paths."""
    frames = 5
    gappy = without_sample(raw_drive, tmp_path / "gappy.mcap", 2)
    proc = subprocess.run(
        stereovox_cmd("demo", "--graph", str(REPO / "deploy" / "local-ins.yaml"), "--recording", str(gappy),
                      "--max-frames", str(frames), "--out", str(tmp_path / "demo"), "--json"),
        cwd=REPO, capture_output=True, text=True, timeout=360, start_new_session=True,
    )
    assert proc.returncode == 0, f"demo failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    assert json.loads(proc.stdout.strip().splitlines()[-1])["frames"] == frames
    run = open_recording(tmp_path / "demo" / "run.mcap")
    assert sorted(run.by_topic("vehicle/motion")) == [0, 1, 3, 4]
    distributed = run.by_topic("odometry/ego")
    fused, plain = tmp_path / "fused.mcap", tmp_path / "plain.mcap"
    process_file(gappy, fused, max_frames=frames, with_frames=False, sets=["odometry.fuse_ins=true"])
    process_file(gappy, plain, max_frames=frames, with_frames=False)
    in_process = open_recording(fused).by_topic("odometry/ego")
    unfused = open_recording(plain).by_topic("odometry/ego")
    assert sorted(distributed) == sorted(in_process) == list(range(frames))
    for i in range(frames):
        assert np.array_equal(distributed[i].pose, in_process[i].pose), i
    assert not np.allclose(in_process[frames - 1].pose, unfused[frames - 1].pose, atol=1e-3)  # fusion did act
