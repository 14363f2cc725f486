"""The bus helper and the bus tools with real Zenoh sessions and real processes on 127.0.0.1."""

from __future__ import annotations

import re
import sys
import threading
import time
from collections.abc import Iterator

import pytest
import zenoh
from conftest import REPO, Processes, free_port, stereovox_cmd, wait_for

from common.bus import FifoSubscriber, LatestSubscriber, Publisher, declare_alive, linger, open_session, subscribe
from common.config import BusConfig, Config
from common.messages import EgoMotion, Health, key_for
from common.recording import open_recording
from services.bus_bench import measure
from services.camera_replay import Replay
from services.topics import summarise


@pytest.fixture
def pair() -> Iterator[tuple[zenoh.Session, zenoh.Session, int]]:
    """A router (listening on a free loopback port) and a client connected to it."""
    port = free_port()
    with (
        open_session(BusConfig(mode="router", listen=[f"tcp/127.0.0.1:{port}"])) as router,
        open_session(BusConfig(mode="client", connect=[f"tcp/127.0.0.1:{port}"])) as client,
    ):
        yield router, client, port


def ego(k: int) -> EgoMotion:
    return EgoMotion(frame_id=k, stamp_ns=k, valid=True)


@pytest.mark.timeout(60)
def test_newest_keeps_the_last_message_and_counts_the_replaced(pair: tuple[zenoh.Session, zenoh.Session, int]) -> None:
    router, client, _ = pair
    sub = subscribe(client, key_for("odometry/ego"), EgoMotion, "newest")
    assert isinstance(sub, LatestSubscriber)
    pub = Publisher(router, key_for("odometry/ego"))
    wait_for(pub.matched, 30, "the subscriber")
    for k in range(50):
        pub.put(ego(k))
    wait_for(lambda: sub.received == 50, 30, "all fifty messages")
    item = sub.recv(1.0)
    assert item is not None and item.msg.frame_id == 49
    assert sub.dropped == 49 and sub.recv(0.05) is None


def test_a_publisher_lingers_only_after_a_recent_put(pair: tuple[zenoh.Session, zenoh.Session, int]) -> None:
    router, _, _ = pair
    quiet, busy = Publisher(router, key_for("odometry/ego")), Publisher(router, key_for("tracker/obstacles"))
    assert linger([quiet, busy], 0.5) == 0.0  # nothing was ever put
    busy.put(ego(0))
    started = time.monotonic()
    waited = linger([quiet, busy], 0.5)
    assert 0.3 < waited <= 0.5 and time.monotonic() - started >= waited
    assert linger([quiet, busy], 0.5) == 0.0  # the last put is now half a second old


@pytest.mark.timeout(60)
def test_a_replay_stopped_after_a_frame_stays_for_it(pair: tuple[zenoh.Session, zenoh.Session, int]) -> None:
    """The camera replay leaves the bus no sooner than ``bus.close_linger_s`` after its last frame,
    as the stages do: a session closed at once can take a frame from a slow subscriber."""
    router, _, _ = pair
    cfg = Config()
    cfg.replay.rate = 0.0
    replay = Replay(cfg, router, open_recording(REPO / "recordings" / "urban.mcap"), threading.Event())
    assert replay.run(loop=False, max_frames=1).frames == 1
    last_put = max(p.last_put for p in replay.pubs.values())
    started = time.monotonic()
    replay.close()
    assert time.monotonic() - last_put >= cfg.bus.close_linger_s
    assert time.monotonic() - started < cfg.bus.close_linger_s + 1.0


@pytest.mark.timeout(60)
def test_fifo_pushes_back_and_loses_nothing(pair: tuple[zenoh.Session, zenoh.Session, int]) -> None:
    router, client, _ = pair
    sub = subscribe(client, key_for("odometry/ego"), EgoMotion, "fifo", depth=4)
    assert isinstance(sub, FifoSubscriber)
    pub = Publisher(router, key_for("odometry/ego"))
    wait_for(pub.matched, 30, "the subscriber")
    sender = threading.Thread(target=lambda: [pub.put(ego(k)) for k in range(200)], daemon=True)
    sender.start()
    got = []
    while len(got) < 200:
        item = sub.recv(10.0)
        assert item is not None, f"stalled after {len(got)} messages"
        assert sub.pending() <= 4
        got.append(item.msg.frame_id)
    sender.join(10)
    assert got == list(range(200)) and sub.dropped == 0 and sub.decode_errors == 0


@pytest.mark.timeout(60)
def test_subscriber_counts_malformed_payloads_and_goes_on(pair: tuple[zenoh.Session, zenoh.Session, int]) -> None:
    router, client, _ = pair
    sub = subscribe(client, key_for("odometry/ego"), EgoMotion, "fifo", depth=16)
    pub = Publisher(router, key_for("odometry/ego"))
    wait_for(pub.matched, 30, "the subscriber")
    for payload in (b"", b"\xff\xfe", Health(frame_id=0, stamp_ns=0, service="x")):
        pub.put(payload)
    pub.put(ego(3))
    item = sub.recv(10.0)
    assert item is not None and item.msg.frame_id == 3
    assert sub.decode_errors == 3 and "Health where EgoMotion" in sub.last_error


def bench_sender(port: int, frames: int, topic: str = "camera/stereo") -> list[str]:
    return [sys.executable, "-m", "services.bus_bench", "--send", "--connect", f"tcp/127.0.0.1:{port}",
            "--frames", str(frames), "--rate", "20", "--topic", topic]


@pytest.mark.timeout(120)
def test_two_processes_exchange_stereo_frames(processes: Processes) -> None:
    """A sender process and ``stereovox topics echo`` in another: every frame, in order, decoded."""
    port = free_port()
    echo = processes.start(
        stereovox_cmd("topics", "echo", "camera/stereo", "--count", "5", "--listen", f"tcp/127.0.0.1:{port}"), "echo"
    )
    sender = processes.start(bench_sender(port, 5), "sender")
    wait_for(lambda: echo.poll() is not None, 90, "echo to print five frames and exit")
    wait_for(lambda: sender.poll() is not None, 30, "the sender to exit once echo left")
    out = processes.log(echo)
    assert echo.returncode == 0 and sender.returncode == 0, out + processes.log(sender)
    lines = [line for line in out.splitlines() if line.startswith("stereovox/ego/camera/stereo ")]
    assert [int(re.search(r" frame_id=(\d+)", line).group(1)) for line in lines] == [0, 1, 2, 3, 4]
    assert all("stereovox.StereoFrame/1" in line and "left=uint8[480x640x3]" in line for line in lines), lines[0]


@pytest.mark.timeout(120)
def test_topics_list_and_hz_see_what_is_on_the_bus(processes: Processes) -> None:
    port = free_port()
    with open_session(BusConfig(mode="router", listen=[f"tcp/127.0.0.1:{port}"])) as router:
        token = declare_alive(router, "test_service", "ego")
        ego_pub = Publisher(router, key_for("odometry/ego"))
        junk_pub = Publisher(router, key_for("odometry/junk"))
        connect = ["--mode", "client", "--connect", f"tcp/127.0.0.1:{port}"]
        hz = processes.start(stereovox_cmd("topics", "hz", "odometry/ego", "--count", "40", *connect), "hz")
        lister = processes.start(stereovox_cmd("topics", "list", "--duration", "3", *connect), "list")
        k = 0
        stop = threading.Event()

        def publish_while_running() -> bool:
            nonlocal k
            if ego_pub.matched():
                ego_pub.put(ego(k))
                junk_pub.put(b"\x00 not a message")
                k += 1
            stop.wait(0.02)
            return hz.poll() is not None and lister.poll() is not None

        wait_for(publish_while_running, 100, "topics hz and topics list to finish", interval=0.0)
        token.undeclare()
    hz_out, list_out = processes.log(hz), processes.log(lister)
    assert hz.returncode == 0 and lister.returncode == 0, hz_out + list_out
    rate = re.search(r"average rate ([\d.]+) Hz over 40 messages", hz_out)
    assert rate is not None and float(rate.group(1)) > 0, hz_out
    assert re.search(r"stereovox/ego/odometry/ego\s+stereovox\.EgoMotion/1\s+\d+", list_out), list_out
    assert re.search(r"stereovox/ego/odometry/junk\s+<not a stereovox message>", list_out), list_out
    assert "stereovox/ego/alive/test_service" in list_out


def test_summarise_shows_arrays_as_dtype_and_shape() -> None:
    import numpy as np

    from common.messages import PointCloud

    cloud = PointCloud(frame_id=4, stamp_ns=5, points=np.zeros((1000, 3), np.float32),
                       colors=np.zeros((1000, 3), np.uint8), timing=[("stereo_depth", 1, 2)])
    text = summarise(cloud)
    assert "points=float32[1000x3]" in text and "colors=uint8[1000x3]" in text and "frame_id=4" in text
    assert "timing=[stereo_depth 0.0ms]" in text


@pytest.mark.timeout(120)
def test_bus_bench_measures_latency_and_rate_between_two_processes() -> None:
    result = measure(frames=20, rate_hz=20.0)
    assert result.frames_received == 20 and result.payload_bytes == 2 * 640 * 480 * 3
    assert 0 < result.latency_p50_ms <= result.latency_p99_ms <= result.latency_max_ms
    assert result.frames_per_s > 0
