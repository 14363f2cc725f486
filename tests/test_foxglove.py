"""Foxglove: exported files and the live server speak Foxglove's own protobuf schemas.

``google.protobuf`` is not installed, so messages are decoded by ``foxglove_wire`` against the
FileDescriptorSet each channel carries: a field or wire type the schema does not declare fails.
"""

from __future__ import annotations

import base64
import json
import re
import socket
import struct
import subprocess
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import REPO, Processes, free_port, stereovox_cmd, wait_for
from foxglove.messages import SceneUpdate
from foxglove_wire import WebSocket, decode, descriptors
from mcap.reader import make_reader
from tiny_run import CALIB, MOVING, STATIONARY, ego_pose, write_run

from common import messages as sv
from common.bus import Publisher, open_session
from common.config import BusConfig
from common.foxglove_convert import TOPICS, Converter

FRAMES = 3


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("export")
    run = write_run(tmp / "run.mcap", frames=FRAMES)
    out = tmp / "view.mcap"
    proc = subprocess.run(stereovox_cmd("export", "foxglove", str(run), "--out", str(out)),
                          capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return out


@pytest.mark.timeout(150)
def test_every_exported_channel_has_a_foxglove_schema_and_decodes(exported: Path) -> None:
    decoded: dict[str, list[dict]] = {}
    with open(exported, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            assert channel.message_encoding == "protobuf", channel.topic
            assert schema is not None and schema.encoding == "protobuf", channel.topic
            assert schema.name == f"foxglove.{TOPICS[channel.topic].__name__}", (channel.topic, schema.name)
            decoded.setdefault(channel.topic, []).append(decode(descriptors(schema.data), schema.name, message.data))
    assert set(decoded) == set(TOPICS)
    assert all(len(decoded[t]) == FRAMES for t in TOPICS if t != "/tf")
    image = decoded["/camera/left"][0]
    assert image["format"] == ["jpeg"] and image["data"][0][:2] == b"\xff\xd8"
    disparity = cv2.imdecode(np.frombuffer(decoded["/disparity"][0]["data"][0], np.uint8), cv2.IMREAD_COLOR)
    assert disparity.shape[:2] == (CALIB.height, CALIB.width)
    assert disparity[:8].max() < 30  # invalid rows black
    assert np.abs(disparity[100, 20].astype(int) - disparity[100, -20].astype(int)).sum() > 100  # near vs far
    cloud = decoded["/points"][0]
    assert cloud["point_stride"] == [16] and len(cloud["data"][0]) == 50 * 16


@pytest.mark.timeout(150)
def test_obstacles_become_coloured_cubes_with_velocity_arrows(exported: Path) -> None:
    with open(exported, "rb") as f:
        updates = [decode(descriptors(s.data), s.name, m.data)
                   for s, _, m in make_reader(f).iter_messages(topics=["/obstacles"])]
    entities = {e["id"][0]: e for e in updates[-1]["entities"]}
    assert set(entities) == {f"obstacle/{MOVING.id}", f"obstacle/{STATIONARY.id}"}
    moving = entities[f"obstacle/{MOVING.id}"]
    cube = moving["cubes"][0]
    size = [cube["size"][0].get(axis, [0.0])[0] for axis in ("x", "y", "z")]
    np.testing.assert_allclose(size, MOVING.bbox_max - MOVING.bbox_min)
    centre = [cube["pose"][0]["position"][0].get(axis, [0.0])[0] for axis in ("x", "y", "z")]
    np.testing.assert_allclose(centre, (MOVING.bbox_min + MOVING.bbox_max) / 2)
    assert cube["color"][0]["r"][0] > 0.9 and cube["color"][0]["g"][0] < 0.3  # moving: red
    arrow = moving["arrows"][0]
    length = arrow["shaft_length"][0] + arrow["head_length"][0]
    assert length == pytest.approx(float(np.linalg.norm(MOVING.velocity)), rel=1e-6)
    still = entities[f"obstacle/{STATIONARY.id}"]
    assert still["cubes"][0]["color"][0]["g"][0] > 0.8 and "arrows" not in still  # stationary: green, no arrow
    assert updates[-1]["deletions"][0]["type"] == [1]  # each frame replaces the last


@pytest.mark.timeout(150)
def test_ego_pose_is_a_world_to_vehicle_transform(exported: Path) -> None:
    with open(exported, "rb") as f:
        transforms = [decode(descriptors(s.data), s.name, m.data)
                      for s, _, m in make_reader(f).iter_messages(topics=["/tf"])]
    ego = [t for t in transforms if t["parent_frame_id"] == ["world"] and t["child_frame_id"] == ["vehicle"]]
    assert len(ego) >= FRAMES
    last = ego[-1]
    xyz = [last["translation"][0].get(a, [0.0])[0] for a in ("x", "y", "z")]
    np.testing.assert_allclose(xyz, ego_pose(FRAMES - 1)[:3, 3], atol=1e-9)
    q = last["rotation"][0]
    yaw = 2 * np.arctan2(q.get("z", [0.0])[0], q.get("w", [0.0])[0])
    assert yaw == pytest.approx(0.02 * (FRAMES - 1))
    cams = [t for t in transforms if t["child_frame_id"] == ["camera"]]
    assert cams and cams[0]["parent_frame_id"] == ["vehicle"]


@pytest.mark.timeout(90)
def test_live_server_advertises_foxglove_schemas_and_streams_obstacles(processes: Processes) -> None:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    router = processes.start(stereovox_cmd("router", "--listen", endpoint), "router")
    wait_for(lambda: _listening(port) or router.poll() is not None, 30, "the router to listen")
    monitor = processes.start(
        stereovox_cmd("monitor", "--foxglove", "--port", "0", "--connect", endpoint), "monitor"
    )
    ports: list[str] = []

    def serving() -> bool:
        ports[:] = re.findall(r"foxglove server at ws://127\.0\.0\.1:(\d+)", processes.log(monitor))
        return bool(ports) or monitor.poll() is not None

    wait_for(serving, 45, "the monitor's Foxglove server")
    assert ports, processes.log(monitor)
    ws = WebSocket("127.0.0.1", int(ports[0]), "foxglove.sdk.v1")
    try:
        assert ws.subprotocol == "foxglove.sdk.v1"
        _, info = ws.recv_until(lambda op, p: op == 1 and json.loads(p)["op"] == "serverInfo", 10)
        assert "stereovox" in json.loads(info)["name"]
        channels: dict[str, dict] = {}
        while set(channels) != set(TOPICS):
            _, adv = ws.recv_until(lambda op, p: op == 1 and json.loads(p)["op"] == "advertise", 10)
            channels.update({c["topic"]: c for c in json.loads(adv)["channels"]})
        for topic, channel in channels.items():
            assert channel["encoding"] == "protobuf" and channel["schemaEncoding"] == "protobuf", channel
            assert channel["schemaName"] == f"foxglove.{TOPICS[topic].__name__}"
        obstacles, left = channels["/obstacles"], channels["/camera/left"]
        ws.send_json({"op": "subscribe", "subscriptions": [{"id": 42, "channelId": obstacles["id"]},
                                                           {"id": 43, "channelId": left["id"]}]})
        tracks = sv.Obstacles(frame_id=1, stamp_ns=time.time_ns(), obstacles=[MOVING], ego_pose=np.eye(4))
        payload = _publish_until_received(ws, endpoint, "tracker/obstacles", tracks, 42)
        update = decode(descriptors(base64.b64decode(obstacles["schema"])), "foxglove.SceneUpdate", payload)
        assert [e["id"][0] for e in update["entities"]] == [f"obstacle/{MOVING.id}"]
        image = np.full((CALIB.height, CALIB.width, 3), 90, dtype=np.uint8)
        frame = sv.StereoFrame(frame_id=1, stamp_ns=time.time_ns(), left=image, right=image, calib=CALIB)
        payload = _publish_until_received(ws, endpoint, "camera/stereo", frame, 43)
        picture = decode(descriptors(base64.b64decode(left["schema"])), "foxglove.CompressedImage", payload)
        assert picture["format"] == ["jpeg"] and picture["frame_id"] == ["camera"]
        assert picture["data"][0][:2] == b"\xff\xd8"
    finally:
        ws.close()


def _listening(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
        return True
    except OSError:
        return False


def _publish_until_received(ws: WebSocket, endpoint: str, topic: str, msg: sv.Message, subscription: int) -> bytes:
    """Publish ``msg`` on the bus until the server forwards it on ``subscription``; its payload."""
    with open_session(BusConfig(mode="client", connect=[endpoint])) as session:
        pub = Publisher(session, sv.key_for(topic))
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            pub.put(msg)
            try:
                _, data = ws.recv_until(
                    lambda op, p: op == 2 and p[0] == 1 and struct.unpack("<I", p[1:5])[0] == subscription, 0.5
                )
                return data[1 + 4 + 8 :]  # opcode, subscription id, log time, then the message
            except TimeoutError:
                continue
        pytest.fail(f"the live server never forwarded {topic}")


def test_trajectory_grows_per_frame_and_restarts_when_the_world_is_re_anchored() -> None:
    schema = SceneUpdate.get_schema()
    table = descriptors(schema.data)
    converter = Converter()

    def line_points(frame: int, epoch: int) -> int:
        ego = sv.EgoMotion(frame_id=frame, stamp_ns=frame, pose=ego_pose(frame), world_epoch=epoch)
        (update,) = [m for topic, m in converter.convert("odometry/ego", ego) if topic == "/trajectory"]
        return len(decode(table, schema.name, update.encode())["entities"][0]["lines"][0]["points"])

    assert [line_points(f, 0) for f in range(3)] == [1, 2, 3]
    assert line_points(2, 0) == 3  # the same frame twice adds nothing
    assert line_points(3, 1) == 1
