"""ROS 2 bags in: a real rosbag2-style MCAP (CDR, ros2msg schemas) written with the mcap project's
ROS 2 writer from rendered stereo frames, imported, and run through the pipeline; bad bags refused."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from mcap_ros2.writer import Writer

from common.datasets import rosbag2
from common.errors import InputError
from common.messages import Obstacles, StereoFrame
from common.recording import open_recording
from services.cli import main as cli_main
from services.pipeline import process_file

SEPARATOR = "=" * 80
DEPENDENCIES = f"""
{SEPARATOR}
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
{SEPARATOR}
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""
IMAGE = """std_msgs/Header header
uint32 height
uint32 width
string encoding
uint8 is_bigendian
uint32 step
uint8[] data""" + DEPENDENCIES
COMPRESSED = """std_msgs/Header header
string format
uint8[] data""" + DEPENDENCIES
CAMERA_INFO = f"""std_msgs/Header header
uint32 height
uint32 width
string distortion_model
float64[] d
float64[9] k
float64[9] r
float64[12] p
uint32 binning_x
uint32 binning_y
sensor_msgs/RegionOfInterest roi{DEPENDENCIES}{SEPARATOR}
MSG: sensor_msgs/RegionOfInterest
uint32 x_offset
uint32 y_offset
uint32 height
uint32 width
bool do_rectify
"""
LEFT, RIGHT = "/stereo/left/image_rect_color", "/stereo/right/image_rect_color"
FRAMES = 6
START_NS = 1_700_000_000_000_000_000


def header(stamp_ns: int, frame: str) -> dict[str, Any]:
    return {"stamp": {"sec": stamp_ns // 1_000_000_000, "nanosec": stamp_ns % 1_000_000_000}, "frame_id": frame}


def info_message(stamp_ns: int, calib: Any, tx: float) -> dict[str, Any]:
    k = [calib.fx, 0.0, calib.cx, 0.0, calib.fy, calib.cy, 0.0, 0.0, 1.0]
    p = [calib.fx, 0.0, calib.cx, tx, 0.0, calib.fy, calib.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    return {"header": header(stamp_ns, "cam"), "height": calib.height, "width": calib.width,
            "distortion_model": "plumb_bob", "d": [0.0] * 5, "k": k, "r": [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0], "p": p,
            "binning_x": 0, "binning_y": 0,
            "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False}}


def bgr8(stamp_ns: int, rgb: np.ndarray, pad: int = 16) -> dict[str, Any]:
    """A raw Image whose rows carry ``pad`` bytes of padding, as some drivers send them."""
    h, w, _ = rgb.shape
    rows = np.zeros((h, w * 3 + pad), dtype=np.uint8)
    rows[:, : w * 3] = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR).reshape(h, w * 3)
    return {"header": header(stamp_ns, "left"), "height": h, "width": w, "encoding": "bgr8", "is_bigendian": 0,
            "step": w * 3 + pad, "data": rows.tobytes()}


def png(stamp_ns: int, rgb: np.ndarray) -> dict[str, Any]:
    ok, data = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    assert ok
    return {"header": header(stamp_ns, "right"), "format": "png", "data": data.tobytes()}


def write_bag(path: Path, frames: list[StereoFrame], swap_info: bool = False, encoding: str = "bgr8") -> list[int]:
    """A two-camera bag: left raw bgr8 (padded rows), right PNG-compressed, right stamps 0.3 ms late,
    one extra left image with no partner, written in a shuffled order of arrival. Returns left stamps."""
    calib = frames[0].calib
    stamps = [START_NS + i * 100_000_000 for i in range(len(frames))]
    with open(path, "wb") as stream:
        writer = Writer(stream)
        image, compressed = writer.register_msgdef("sensor_msgs/msg/Image", IMAGE), writer.register_msgdef(
            "sensor_msgs/msg/CompressedImage", COMPRESSED)
        info = writer.register_msgdef("sensor_msgs/msg/CameraInfo", CAMERA_INFO)
        tx = -calib.fx * calib.baseline
        left_tx, right_tx = (tx, 0.0) if swap_info else (0.0, tx)
        writer.write_message("/stereo/left/camera_info", info, info_message(stamps[0], calib, left_tx), START_NS)
        writer.write_message("/stereo/right/camera_info", info, info_message(stamps[0], calib, right_tx), START_NS)
        for i, (frame, stamp) in enumerate(zip(frames, stamps, strict=True)):
            left_msg = bgr8(stamp, frame.left)
            if encoding != "bgr8":
                left_msg["encoding"] = encoding
            right = ("right", png(stamp + 300_000, frame.right))
            left = ("left", left_msg)
            for side, msg in (right, left) if i % 2 else (left, right):
                topic, schema = (LEFT, image) if side == "left" else (RIGHT, compressed)
                writer.write_message(topic, schema, msg, stamp + (1_000_000 if side == "left" else 2_000_000))
        lone = stamps[-1] + 100_000_000
        writer.write_message(LEFT, image, bgr8(lone, frames[0].left), lone)
        writer.finish()
    return stamps


@pytest.fixture(scope="module")
def source_frames(tmp_path_factory: pytest.TempPathFactory) -> list[StereoFrame]:
    from common.scenarios.simulate import simulate_to_file

    path = simulate_to_file("urban", tmp_path_factory.mktemp("bag") / "urban.mcap", frames=FRAMES, seed=3)
    frames = [m for _, m in open_recording(path).messages() if isinstance(m, StereoFrame)]
    assert len(frames) == FRAMES
    return frames


TOPICS = rosbag2.Topics.of(LEFT, RIGHT, None, None)


@pytest.mark.timeout(120)
def test_a_ros2_bag_becomes_stereo_frames_the_pipeline_runs_on(
    source_frames: list[StereoFrame], tmp_path: Path
) -> None:
    bag = tmp_path / "drive.mcap"
    stamps = write_bag(bag, source_frames)
    out = tmp_path / "drive_rec.mcap"
    written, unpaired = rosbag2.import_bag(bag, TOPICS, out, camera_height=1.5)
    assert (written, unpaired) == (FRAMES, 1)

    rec = open_recording(out)
    frames = [m for _, m in rec.messages() if isinstance(m, StereoFrame)]
    assert [f.frame_id for f in frames] == list(range(FRAMES))
    assert [f.stamp_ns for f in frames] == stamps  # the left camera's header stamps
    truth = source_frames[0].calib
    for got, want in zip(frames, source_frames, strict=True):
        np.testing.assert_array_equal(got.left, want.left)  # padding stripped, BGR turned to RGB
        np.testing.assert_array_equal(got.right, want.right)  # PNG decoded
        assert (got.calib.fx, got.calib.cx, got.calib.cy, got.calib.width) == (truth.fx, truth.cx, truth.cy, 640)
        assert got.calib.baseline == pytest.approx(truth.baseline)
        np.testing.assert_allclose(got.calib.cam_to_vehicle, truth.cam_to_vehicle, atol=1e-12)
    info = rec.info()
    assert info["source"] == "rosbag2" and info["frames"] == FRAMES
    assert info["frame_rate_hz"] == pytest.approx(10.0)

    first = tmp_path / "first3.mcap"
    assert rosbag2.import_bag(bag, TOPICS, first, camera_height=1.5, max_frames=3) == (3, 1)
    assert [m.stamp_ns for _, m in open_recording(first).messages()] == stamps[:3]

    run = tmp_path / "drive_run.mcap"
    process_file(out, run)
    obstacles = [m for _, m in open_recording(run).messages() if isinstance(m, Obstacles)]
    assert len(obstacles) == FRAMES
    assert any(o.obstacles for o in obstacles)  # the rendered street's cars and walls are found


def test_pairs_take_the_nearest_partner_and_never_a_far_one() -> None:
    left = [100, 200, 300, 400]
    right = [101, 199, 250, 402, 500]
    assert rosbag2.pair_stamps(left, right, 2) == [(100, 101), (200, 199), (400, 402)]
    assert rosbag2.pair_stamps(left[::-1], right, 0) == []
    assert rosbag2.pair_stamps([100, 100], [100], 0) == [(100, 100)]


def test_a_topic_not_in_the_bag_lists_the_image_topics(source_frames: list[StereoFrame], tmp_path: Path) -> None:
    bag = tmp_path / "drive.mcap"
    write_bag(bag, source_frames[:2])
    with pytest.raises(InputError, match=r"/camera/left is not in the bag.*/stereo/left/image_rect_color"):
        rosbag2.import_bag(bag, rosbag2.Topics.of("/camera/left", RIGHT, None, None), tmp_path / "o.mcap", 1.5)
    with pytest.raises(InputError, match=r"/stereo/left/camera_info is a sensor_msgs/msg/CameraInfo"):
        rosbag2.import_bag(bag, rosbag2.Topics.of("/stereo/left/camera_info", RIGHT, None, None),
                           tmp_path / "o.mcap", 1.5)
    assert not (tmp_path / "o.mcap").exists()


def test_swapped_cameras_and_unknown_encodings_are_named(source_frames: list[StereoFrame], tmp_path: Path) -> None:
    swapped = tmp_path / "swapped.mcap"
    write_bag(swapped, source_frames[:2], swap_info=True)
    with pytest.raises(InputError, match="swapped"):
        rosbag2.import_bag(swapped, TOPICS, tmp_path / "o.mcap", 1.5)
    depth = tmp_path / "depth.mcap"
    write_bag(depth, source_frames[:2], encoding="16UC1")
    with pytest.raises(InputError, match=r"/stereo/left/image_rect_color: image encoding '16UC1' not supported"):
        rosbag2.import_bag(depth, TOPICS, tmp_path / "o.mcap", 1.5)
    assert not (tmp_path / "o.mcap").exists() and not (tmp_path / "o.mcap.part").exists()


def test_a_cut_bag_is_named_and_the_cli_exits_2(source_frames: list[StereoFrame], tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    bag = tmp_path / "drive.mcap"
    write_bag(bag, source_frames[:2])
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(bag.read_bytes()[: bag.stat().st_size // 2])
    with pytest.raises(InputError, match=str(cut)):
        rosbag2.import_bag(cut, TOPICS, tmp_path / "o.mcap", 1.5)
    code = cli_main(["import", "rosbag2", str(bag), "--left", "/nope", "--right", RIGHT, "--camera-height", "1.5",
                     "--out", str(tmp_path / "o.mcap")])
    assert code == 2
    assert "/nope is not in the bag" in capsys.readouterr().err
    assert not list(tmp_path.glob("o.mcap*"))
