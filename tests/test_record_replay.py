"""The recorder and the replay as real processes on 127.0.0.1, around an in-test Zenoh router."""

from __future__ import annotations

import itertools
import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
import zenoh
from conftest import Processes, free_port, stereovox_cmd, wait_for
from fake_recording import CALIB, PERIOD_NS, START_NS, write_recording
from fake_recording import frame as fake_frame
from mcap.reader import make_reader

from common.bus import Publisher, declare_alive, open_session, watch_alive
from common.codec import decode, encode
from common.config import BusConfig, Config
from common.errors import DecodeError
from common.messages import Health, Message, Obstacles, StereoFrame, key_for
from common.recording import RecordingWriter, open_recording, peek_stamp
from services.camera_replay import stereo_wire

pytestmark = pytest.mark.timeout(120)

CAMERA = key_for("camera/stereo")
GT_KEYS = (key_for("groundtruth/ego"), key_for("groundtruth/objects"))


@dataclass
class Hub:
    """A router the processes connect to, and a session the test observes the bus through."""

    session: zenoh.Session
    endpoint: str
    health: dict[str, Health] = field(default_factory=dict)
    alive: set[str] = field(default_factory=set)

    def listen(self, key: str, on_msg: Callable[[str, Message, int], None]) -> zenoh.Subscriber:
        def handler(sample: zenoh.Sample) -> None:
            on_msg(str(sample.key_expr), decode(sample.payload.to_bytes()), time.monotonic_ns())

        return self.session.declare_subscriber(key, handler)

    def written(self, topic: str) -> int:
        """Messages of one topic the recorder reports written (from its Health)."""
        h = self.health.get("recorder")
        return int(h.detail.get("written_by_topic", {}).get(topic, 0)) if h else 0


@pytest.fixture
def hub() -> Iterator[Hub]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with open_session(BusConfig(mode="router", listen=[endpoint])) as session:
        h = Hub(session, endpoint)

        def on_health(key: str, msg: Message, t: int) -> None:
            assert isinstance(msg, Health)
            h.health[msg.service] = msg

        def on_alive(service: str, up: bool) -> None:
            (h.alive.add if up else h.alive.discard)(service)

        sub = h.listen(key_for("health/*"), on_health)
        watcher = watch_alive(session, "ego", on_alive)
        yield h
        watcher.undeclare()
        sub.undeclare()


def wait_line(processes: Processes, proc: subprocess.Popen[bytes], text: str, timeout: float = 40.0) -> None:
    def seen() -> bool:
        if text in processes.log(proc):
            return True
        if proc.poll() is not None:
            pytest.fail(f"process exited with {proc.returncode} before printing {text!r}:\n{processes.log(proc)}")
        return False

    wait_for(seen, timeout, repr(text))


def start_recorder(processes: Processes, hub: Hub, out: Path, *extra: str) -> subprocess.Popen[bytes]:
    cmd = stereovox_cmd("record", "--out", str(out), "--connect", hub.endpoint, "--set", "health_period_s=0.2", *extra)
    proc = processes.start(cmd, "recorder")
    wait_line(processes, proc, "recorder ready")
    # "ready" means subscribed in its own session; the token, declared after the subscriber, reaching
    # the router means the router knows the subscription too, so nothing the test publishes is lost.
    wait_for(lambda: "recorder" in hub.alive, 20, "the recorder's liveliness token")
    return proc


def publish_frames(hub: Hub, count: int, size: tuple[int, int] = (48, 64)) -> None:
    pub = Publisher(hub.session, CAMERA)
    rng = np.random.default_rng(3)
    for i in range(count):
        img = rng.integers(0, 256, (*size, 3), dtype=np.uint8)
        pub.put(StereoFrame(frame_id=i, stamp_ns=i * 1000, left=img, right=img, calib=CALIB))
    pub.close()


def test_record_replay_record_keeps_every_payload(tmp_path: Path, processes: Processes, hub: Hub) -> None:
    source, again = tmp_path / "source.mcap", tmp_path / "again.mcap"
    write_recording(source, 20)
    recorder = start_recorder(processes, hub, again, "--info-from", str(source))
    replay = processes.start(
        stereovox_cmd("replay", str(source), "--max", "--wait-for", "recorder", "--connect", hub.endpoint), "replay"
    )
    assert replay.wait(60) == 0, processes.log(replay)
    assert "replay done: 20 frames, 40 other messages" in processes.log(replay)
    wait_for(lambda: all(hub.written(t) == 20 for t in ("camera/stereo", "groundtruth/ego", "groundtruth/objects")),
             30, "the recorder to write 20 messages of each key")
    assert processes.stop(recorder, signal.SIGINT) == 0, processes.log(recorder)
    assert "recorder done" in processes.log(recorder)

    original, copy = open_recording(source), open_recording(again)
    for key in GT_KEYS:  # ground truth goes through replay and recorder byte for byte, with its times
        a, b = list(original.raw([key])), list(copy.raw([key]))
        assert [r.data for r in a] == [r.data for r in b]
        assert [r.publish_time_ns for r in a] == [r.publish_time_ns for r in b]
    replayed = list(copy.raw([CAMERA]))
    for rec, (_, first) in zip(replayed, original.messages(keys=[CAMERA]), strict=True):
        second = decode(rec.data, StereoFrame)
        assert isinstance(first, StereoFrame)
        assert (second.frame_id, second.stamp_ns) == (first.frame_id, first.stamp_ns)
        assert rec.publish_time_ns == first.stamp_ns and rec.log_time_ns >= second.timing[0][1]
        np.testing.assert_array_equal(second.left, first.left)
        np.testing.assert_array_equal(second.right, first.right)
        assert second.calib.baseline == first.calib.baseline and second.calib.width == first.calib.width
        [(stage, start, end)] = second.timing  # a fresh trail, not the recording's
        assert stage == "camera_replay" and start == end and start > first.stamp_ns
    # SIGINT finished the file: summary present, configuration stored
    with open(again, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None and summary.statistics.message_count >= 60
    assert copy.truncated is None
    assert copy.config_dict() is not None and copy.config_dict()["recorder"]["compression"] == "zstd"
    assert copy.info() == original.info() | {"recorded_keys": "stereovox/**", "part": 0,
                                             "recorded_by": "stereovox record"}


def test_sigkill_loses_at_most_one_chunk(tmp_path: Path, processes: Processes, hub: Hub) -> None:
    out = tmp_path / "killed.mcap"
    chunk = 100_000  # frames are ~18.5 KB: at most 6 of them sit in an unfinished chunk
    recorder = start_recorder(processes, hub, out, "--set", f"recorder.chunk_size={chunk}",
                              "--set", "recorder.flush_interval_s=1000", "--compression", "lz4")
    sent = 60
    publish_frames(hub, sent)
    wait_for(lambda: hub.written("camera/stereo") == sent, 30, "the recorder to write every frame")
    assert processes.stop(recorder, signal.SIGKILL) == -signal.SIGKILL
    reader = open_recording(out)
    frames = [m.frame_id for _, m in reader.messages(keys=[CAMERA])]
    per_chunk = chunk // (2 * 48 * 64 * 3) + 1
    assert sent - per_chunk <= len(frames) <= sent
    assert frames == list(range(len(frames)))
    assert reader.truncated is not None  # no summary: SIGKILL gave it no chance


def test_a_stopped_recorder_keeps_what_is_still_arriving(tmp_path: Path, processes: Processes, hub: Hub) -> None:
    """SIGINT while messages still come, 0.1 s apart: the recorder waits for a quiet bus and keeps them all.

    This is the shutdown of a pipeline: the recorder is stopped after its stages, and their last
    messages may still be on the way through the router.
    """
    out = tmp_path / "stopped.mcap"
    # quiet 10 times the gap, and no cap worth the name: a loaded machine must not stop it early
    recorder = start_recorder(processes, hub, out, "--set", "recorder.stop_quiet_s=1.0",
                              "--set", "recorder.stop_quiet_max_s=30")
    pub = Publisher(hub.session, CAMERA)
    img = np.zeros((48, 64, 3), dtype=np.uint8)
    sent = 12
    for i in range(sent):
        pub.put(StereoFrame(frame_id=i, stamp_ns=i * 1000, left=img, right=img, calib=CALIB))
        if i == 2:
            wait_for(lambda: hub.written("camera/stereo") >= 1, 30, "the first frame written")
            os.killpg(recorder.pid, signal.SIGINT)
        time.sleep(0.1)
    pub.close()
    assert recorder.wait(30) == 0, processes.log(recorder)
    assert [m.frame_id for _, m in open_recording(out).messages(keys=[CAMERA])] == list(range(sent))


def test_unwritable_path_fails_clearly(tmp_path: Path, processes: Processes, hub: Hub) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("not a directory")
    out = blocker / "run.mcap"
    proc = processes.start(stereovox_cmd("record", "--out", str(out), "--connect", hub.endpoint), "recorder")
    assert proc.wait(40) == 2
    log = processes.log(proc)
    assert str(out) in log and "cannot write" in log and "Traceback" not in log


def test_full_disk_stops_the_recorder_not_the_pipeline(tmp_path: Path, processes: Processes, hub: Hub) -> None:
    """/dev/full refuses every write with ENOSPC: the recorder must exit naming it; traffic flows on."""
    cmd = stereovox_cmd("record", "--out", "/dev/full", "--connect", hub.endpoint,
                        "--set", "recorder.flush_interval_s=0.2")
    recorder = processes.start(cmd, "recorder")
    assert recorder.wait(40) == 2
    log = processes.log(recorder)
    assert "/dev/full" in log and "No space left on device" in log and "Traceback" not in log
    seen: list[int] = []
    sub = hub.listen(CAMERA, lambda k, m, t: seen.append(m.frame_id))
    publish_frames(hub, 10)
    wait_for(lambda: len(seen) == 10, 20, "frames to keep flowing without the recorder")
    sub.undeclare()


class FakeTracker:
    """Answers every camera frame with Obstacles after a delay, except the frames in ``silent``."""

    def __init__(self, hub: Hub, delay_s: float, silent: set[int]) -> None:
        self.pub = Publisher(hub.session, key_for("tracker/obstacles"))
        self.delay_s, self.silent = delay_s, silent
        self.received: dict[int, int] = {}  # frame id -> when it arrived (monotonic ns)
        self.replied: dict[int, int] = {}
        self.sub = hub.listen(CAMERA, self._on_frame)
        self.token = declare_alive(hub.session, "tracker", "ego")

    def _on_frame(self, key: str, msg: Message, t: int) -> None:
        self.received[msg.frame_id] = t
        if msg.frame_id not in self.silent:
            threading.Timer(self.delay_s, self._reply, (msg,)).start()

    def _reply(self, msg: Message) -> None:
        self.replied[msg.frame_id] = time.monotonic_ns()
        self.pub.put(Obstacles(frame_id=msg.frame_id, stamp_ns=msg.stamp_ns))

    def close(self) -> None:
        self.token.undeclare()
        self.sub.undeclare()


def test_lockstep_waits_for_obstacles_and_reports_a_timeout(
    tmp_path: Path, processes: Processes, hub: Hub
) -> None:
    source = tmp_path / "source.mcap"
    write_recording(source, 8)
    replay = processes.start(
        stereovox_cmd("replay", str(source), "--lockstep", "--connect", hub.endpoint,
                      "--set", "replay.lockstep_timeout_s=1.5"),
        "replay",
    )
    alive: list[str] = []
    watcher = hub.session.liveliness().declare_subscriber(key_for("alive/*"), lambda s: alive.append(str(s.key_expr)),
                                                          history=True)
    frames_early: list[int] = []
    early = hub.listen(CAMERA, lambda k, m, t: frames_early.append(m.frame_id))
    wait_for(lambda: key_for("alive/camera_replay") in alive, 40, "the replay's liveliness token")
    early.undeclare()
    assert frames_early == []  # it waits for the tracker instead of publishing into the void
    tracker = FakeTracker(hub, delay_s=0.15, silent={3})
    assert replay.wait(60) == 0, processes.log(replay)
    tracker.close()
    watcher.undeclare()
    log = processes.log(replay)
    assert "no tracker/obstacles for frame 3 within 1.5 s" in log and "1 lockstep timeouts" in log
    wait_for(lambda: "camera_replay" in hub.health and hub.health["camera_replay"].frames_out == 8, 10,
             "the replay's last Health report")
    assert hub.health["camera_replay"].detail["lockstep_timeouts"] == 1
    assert sorted(tracker.received) == list(range(8))
    for k in range(7):
        if k == 3:  # no reply: frame 4 waited out the timeout after frame 3
            assert tracker.received[4] - tracker.received[3] >= 1.4e9
        else:  # frame k+1 left only after the reply for frame k
            assert tracker.received[k + 1] >= tracker.replied[k]


def test_loop_keeps_frame_ids_increasing(tmp_path: Path, processes: Processes, hub: Hub) -> None:
    """Also: PNG on the wire gives back the recorded pixels exactly."""
    source = tmp_path / "source.mcap"
    write_recording(source, 6)
    got: dict[str, list[tuple[int, int, int]]] = {}
    frames: list[Message] = []

    def on_msg(key: str, msg: Message, t: int) -> None:
        got.setdefault(key, []).append((msg.frame_id, msg.stamp_ns, t))
        if key == CAMERA:
            frames.append(msg)

    sub = hub.listen("stereovox/ego/**", on_msg)
    token = declare_alive(hub.session, "monitor", "ego")
    replay = processes.start(
        stereovox_cmd("replay", str(source), "--rate", "4", "--loop", "--max-frames", "15", "--wait-for", "monitor",
                      "--image-format", "png", "--connect", hub.endpoint),
        "replay",
    )
    assert replay.wait(60) == 0, processes.log(replay)
    wait_for(lambda: len(got.get(GT_KEYS[1], [])) == 15, 20, "15 ground-truth frames")
    sub.undeclare()
    token.undeclare()
    for key in (CAMERA, *GT_KEYS):
        ids = [i for i, _, _ in got[key]]
        stamps = [s for _, s, _ in got[key]]
        assert ids == list(range(15)), key
        assert all(b > a for a, b in itertools.pairwise(stamps)), key
    # at 4x the recorded 10 Hz, 15 frames cannot go out in less than 14 periods of 25 ms (their trails
    # carry the publish times, so delivery jitter on a loaded machine cannot shorten the span)
    published = [f.timing[0][1] for f in frames]
    assert published[-1] - published[0] >= 0.95 * 14 * 25e6  # (--max would take a few ms)
    assert "2 passes" in processes.log(replay)  # two whole passes and part of a third
    recorded = [m for _, m in open_recording(source).messages(keys=[CAMERA])]
    for i, f in enumerate(frames):
        assert isinstance(f, StereoFrame) and f.image_format == "png"
        np.testing.assert_array_equal(f.left, recorded[i % 6].left)
        np.testing.assert_array_equal(f.right, recorded[i % 6].right)


def test_recorded_images_go_out_as_stored(tmp_path: Path, processes: Processes, hub: Hub) -> None:
    """``--image-format recorded``: JPEG frames leave as JPEG, renumbered with a fresh trail, same pixels."""
    source = tmp_path / "jpeg.mcap"
    rng = np.random.default_rng(3)
    with RecordingWriter(source) as w:
        w.describe(Config().to_dict(), {"source": "synthetic", "frames": 4, "frame_rate_hz": 10.0})
        for i in range(4):
            w.write(CAMERA, fake_frame(i, rng, "jpeg"), log_time_ns=START_NS + i * PERIOD_NS)
    frames: list[StereoFrame] = []
    sub = hub.listen(CAMERA, lambda key, msg, t: frames.append(msg))  # type: ignore[arg-type]
    token = declare_alive(hub.session, "monitor", "ego")
    replay = processes.start(
        stereovox_cmd("replay", str(source), "--max", "--loop", "--max-frames", "6", "--wait-for", "monitor",
                      "--image-format", "recorded", "--connect", hub.endpoint),
        "replay",
    )
    assert replay.wait(60) == 0, processes.log(replay)
    wait_for(lambda: len(frames) == 6, 20, "6 frames")
    sub.undeclare()
    token.undeclare()
    recorded = [m for _, m in open_recording(source).messages(keys=[CAMERA])]
    assert [f.frame_id for f in frames] == list(range(6))  # the second pass numbered on
    for i, f in enumerate(frames):
        assert f.image_format == "jpeg" and [stage for stage, _, _ in f.timing] == ["camera_replay"]
        np.testing.assert_array_equal(f.left, recorded[i % 4].left)
        np.testing.assert_array_equal(f.right, recorded[i % 4].right)


@pytest.mark.parametrize("data", [b"\xc1", encode(Health(frame_id=1, stamp_ns=1, service="x")),
                                  encode(fake_frame(0, np.random.default_rng(0)))[:-40]])
def test_a_recorded_frame_that_is_no_stereo_frame_is_named(data: bytes) -> None:
    with pytest.raises(DecodeError, match="StereoFrame"):
        stereo_wire(data)


def test_truncated_recording_replays_its_readable_part(tmp_path: Path, processes: Processes) -> None:
    source = tmp_path / "cut.mcap"
    write_recording(source, 20, chunk_size=30_000)
    with open(source, "r+b") as f:
        f.truncate(source.stat().st_size // 2)
    readable = len(list(open_recording(source).messages(keys=[CAMERA])))
    replay = processes.start(stereovox_cmd("replay", str(source), "--max"), "replay")
    assert replay.wait(60) == 0
    log = processes.log(replay)
    assert f"replay done: {readable} frames" in log
    assert "WARNING" in log and str(source) in log and "at byte" in log and "TRUNCATED" in log


def test_a_corrupt_frame_is_skipped_and_reported(tmp_path: Path, processes: Processes) -> None:
    source = tmp_path / "corrupt.mcap"
    write_recording(source, 3)
    with RecordingWriter(tmp_path / "with_bad.mcap") as w:
        for rec in open_recording(source).raw():
            w.write(rec.key, rec.data, rec.log_time_ns, rec.publish_time_ns)
            if rec.key == CAMERA and peek_stamp(rec.data) == (1, rec.publish_time_ns):
                w.write(CAMERA, b"\x81\xa6schema\xa5bogus", rec.log_time_ns)  # decodes to nothing known
    replay = processes.start(stereovox_cmd("replay", str(tmp_path / "with_bad.mcap"), "--max"), "replay")
    assert replay.wait(60) == 0
    log = processes.log(replay)
    assert "replay done: 3 frames, 6 other messages, 1 passes, 0 lockstep timeouts, 1 skipped" in log
    assert f"skipped a message on {CAMERA}" in log and "unknown schema" in log


def test_not_mcap_is_named_and_exits_2(tmp_path: Path) -> None:
    bogus = tmp_path / "bogus.mcap"
    bogus.write_text("these are notes, not a recording")
    proc = subprocess.run(stereovox_cmd("replay", str(bogus)), capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert str(bogus) in proc.stderr and "not an MCAP file" in proc.stderr


def test_split_by_size_names_parts_and_keeps_every_message(tmp_path: Path, processes: Processes, hub: Hub) -> None:
    out = tmp_path / "run.mcap"
    recorder = start_recorder(processes, hub, out, "--split-size", "0.2", "--set", "recorder.chunk_size=50000",
                              "--compression", "none", "--mode", "peer")
    publish_frames(hub, 40)  # ~0.75 MB of frames: four parts of 0.2 MB (plus at most a chunk each)
    wait_for(lambda: hub.written("camera/stereo") == 40, 30, "the recorder to write every frame")
    assert processes.stop(recorder, signal.SIGTERM) == 0, processes.log(recorder)  # SIGTERM finishes files too
    parts = sorted(tmp_path.glob("run_*.mcap"), key=lambda p: int(p.stem.split("_")[1]))
    assert not out.exists() and len(parts) >= 3
    assert [p.name for p in parts] == [f"run_{i}.mcap" for i in range(len(parts))]
    ids: list[int] = []
    for part in parts:
        reader = open_recording(part)
        ids += [m.frame_id for _, m in reader.messages(keys=[CAMERA])]
        assert reader.truncated is None and reader.config_dict() is not None  # each part is complete
    assert ids == list(range(40))
    assert all(p.stat().st_size < 0.2 * 1024 * 1024 + 2 * 50_000 for p in parts)


def test_split_by_duration_starts_new_parts(tmp_path: Path, processes: Processes, hub: Hub) -> None:
    out = tmp_path / "timed.mcap"
    recorder = start_recorder(processes, hub, out, "--split-duration", "0.3")
    pub = Publisher(hub.session, CAMERA)
    sent = 0
    while hub.health.get("recorder") is None or hub.health["recorder"].detail["files"] < 3:
        assert sent < 500, "no third part after 500 frames"
        img = np.full((48, 64, 3), sent % 256, dtype=np.uint8)
        pub.put(StereoFrame(frame_id=sent, stamp_ns=sent, left=img, right=img, calib=CALIB))
        sent += 1
        wait_for(lambda n=sent: hub.written("camera/stereo") == n, 20, f"frame {sent} written")
    pub.close()
    assert processes.stop(recorder, signal.SIGINT) == 0, processes.log(recorder)
    parts = [tmp_path / f"timed_{i}.mcap" for i in range(3)]
    ids = [m.frame_id for p in parts for _, m in open_recording(p).messages(keys=[CAMERA])]
    assert ids == list(range(sent))


@pytest.mark.parametrize("when_full", ["drop", "block"])
def test_full_queue_accounting(tmp_path: Path, processes: Processes, hub: Hub, when_full: str) -> None:
    """A queue of 10 KB holds one 18 KB frame: ``drop`` counts every frame it could not keep, ``block`` keeps all."""
    out = tmp_path / f"{when_full}.mcap"
    recorder = start_recorder(processes, hub, out, "--when-full", when_full, "--set", "recorder.queue_mb=0.01")
    sent = 150
    publish_frames(hub, sent)

    def counts() -> tuple[int, int]:
        h = hub.health.get("recorder")
        if h is None:
            return 0, 0
        topic = "camera/stereo"
        return h.detail["written_by_topic"].get(topic, 0), h.detail["dropped_by_topic"].get(topic, 0)

    wait_for(lambda: sum(counts()) >= sent, 30, "every frame written or counted as dropped")
    written, dropped = counts()
    assert processes.stop(recorder, signal.SIGINT) == 0, processes.log(recorder)
    frames = [m.frame_id for _, m in open_recording(out).messages(keys=[CAMERA])]
    assert len(frames) == written == sent - dropped
    assert frames == sorted(frames)
    if when_full == "block":
        assert dropped == 0 and frames == list(range(sent))
