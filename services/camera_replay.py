"""``stereovox replay``: a recording's camera frames and ground truth back onto the bus.

Timing is the recording's (``publish_time``, the capture stamp) scaled by ``--rate``, or none
(``--max``), or the pipeline's own (``--lockstep``: frame k+1 goes out only once the tracker has
published Obstacles for frame k; a reply that does not come within ``replay.lockstep_timeout_s``
is logged, counted in Health and the summary, and replay goes on). ``--lockstep-on
stereo_depth/points`` paces by the first stage instead: the camera runs exactly as fast as stereo
takes frames, and the later stages work on frame k while stereo works on k+1 — the pipeline's
own top rate, without a flood of frames that only get dropped. Every StereoFrame gets a
fresh timing trail ``[("camera_replay", t, t)]`` so latencies never depend on when the data was
recorded; ground truth of the first pass goes out byte for byte as recorded. Before the first
frame the replay waits for the liveliness tokens of the services it feeds (``--wait-for``; the
tracker by default in lockstep), instead of sleeping and hoping.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgpack
import zenoh

from common.bus import Publisher, declare_alive, linger, open_session, subscribe, watch_alive
from common.codec import decode, encode
from common.config import Config
from common.errors import BusError, ConfigError, DecodeError
from common.messages import TOPICS, StereoFrame, key_for, now_ns, topic_of
from common.recording import RawRecord, RecordingReader, open_recording, peek_stamp
from common.wire_arrays import IMAGE_FORMATS
from services.health import HealthReporter, StageHealth
from services.replay_clock import Pacer, Renumbering
from services.service_args import add_bus_arguments, config_from_args, stop_on_signals

log = logging.getLogger(__name__)

CAMERA_TOPIC = "camera/stereo"
#: "recorded": the images go out as the recording holds them (JPEG, PNG or raw), neither decoded
#: nor encoded again here; the stages that use them decode them.
RECORDED = "recorded"
REPLAY_FORMATS: tuple[str, ...] = (*IMAGE_FORMATS, RECORDED)


@dataclass
class ReplayStats:
    frames: int = 0
    other: int = 0  # ground truth and any other replayed message
    passes: int = 0
    lockstep_timeouts: int = 0
    skipped: int = 0  # messages that did not decode
    truncated: str = ""


def stereo_wire(data: bytes) -> dict[str, Any]:
    """A recorded StereoFrame as its msgpack map, images left encoded; the envelope is checked.

    The images themselves are checked where they are decoded, by every stage that receives them.
    """
    try:
        wire = msgpack.unpackb(data, raw=False)
    except (ValueError, msgpack.UnpackException) as exc:
        raise DecodeError(f"StereoFrame: not msgpack ({exc})") from None
    if not isinstance(wire, dict) or wire.get("schema") != StereoFrame.SCHEMA or not isinstance(wire.get("body"), dict):
        raise DecodeError("StereoFrame: not a StereoFrame envelope")
    wire_stamp(wire)
    return wire


def wire_stamp(wire: dict[str, Any]) -> tuple[int, int]:
    """Frame id and capture stamp of a StereoFrame's msgpack map."""
    body = wire["body"]
    frame_id, stamp = body.get("frame_id"), body.get("stamp_ns")
    if not isinstance(frame_id, int) or not isinstance(stamp, int) or isinstance(frame_id, bool):
        raise DecodeError("StereoFrame: frame_id and stamp_ns must be integers")
    return frame_id, stamp


def wait_for_services(session: zenoh.Session, cfg: Config, names: list[str], stop: threading.Event) -> None:
    """Return once every named service's liveliness token is present; BusError after the timeout."""
    alive: set[str] = set()
    cond = threading.Condition()

    def on_change(service: str, up: bool) -> None:
        with cond:
            (alive.add if up else alive.discard)(service)
            cond.notify_all()

    watcher = watch_alive(session, cfg.bus.vehicle, on_change)
    deadline = time.monotonic() + cfg.replay.wait_timeout_s
    try:
        with cond:
            while not set(names) <= alive and not stop.is_set():
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    missing = sorted(set(names) - alive)
                    raise BusError(
                        f"waited {cfg.replay.wait_timeout_s:.0f} s for services {missing} to come up "
                        f"(alive: {sorted(alive)}); is the pipeline running and connected?"
                    )
                cond.wait(min(remaining, 0.2))
    finally:
        watcher.undeclare()


class Replay:
    """Publishes one recording, pass after pass, with the configured pacing."""

    def __init__(self, cfg: Config, session: zenoh.Session, reader: RecordingReader, stop: threading.Event) -> None:
        rc = cfg.replay
        if rc.image_format not in REPLAY_FORMATS:
            raise ConfigError(f"replay.image_format must be one of {REPLAY_FORMATS}, got {rc.image_format!r}")
        self.cfg, self.session, self.reader, self.stop = cfg, session, reader, stop
        self.stats = ReplayStats()
        self.renumber = Renumbering()
        self.pacer = Pacer(0.0 if rc.lockstep else rc.rate, stop)
        try:
            self.topics = [zenoh.KeyExpr(t) for t in rc.topics]
        except zenoh.ZError as exc:
            raise ConfigError(f"replay.topics {rc.topics!r}: not valid key expressions ({exc})") from None
        self.pubs: dict[str, Publisher] = {}
        if rc.lockstep and rc.lockstep_topic not in TOPICS:
            raise ConfigError(f"replay.lockstep_topic {rc.lockstep_topic!r} is none of {sorted(TOPICS)}")
        # FIFO, not newest: every report is taken, so Health shows no "dropped" reports that were merely superseded
        self.reports = (
            subscribe(session, key_for(rc.lockstep_topic, cfg.bus.vehicle), TOPICS[rc.lockstep_topic], "fifo", depth=64)
            if rc.lockstep
            else None
        )
        self._in_flight: list[int] = []  # frame ids sent whose report lockstep still awaits, oldest first
        self._done = -1  # highest frame id reported
        self.health = StageHealth("camera_replay", [self.reports] if self.reports else [])
        self.health.extra |= {
            "lockstep_timeouts": lambda: self.stats.lockstep_timeouts,
            "other_messages": lambda: self.stats.other,
            "passes": lambda: self.stats.passes,
            "truncated": lambda: self.stats.truncated,
        }

    def _wanted(self, topic: str) -> bool:
        return any(t.includes(zenoh.KeyExpr(topic)) for t in self.topics)

    def run(self, loop: bool, max_frames: int) -> ReplayStats:
        last_id: int | None = None
        while not self.stop.is_set():
            for rec in self.reader.raw():
                topic = topic_of(rec.key)
                if self.stop.is_set():
                    break
                if not self._wanted(topic):
                    continue
                header = peek_stamp(rec.data)
                frame_id, stamp = self.renumber.apply(*header) if header else (None, rec.publish_time_ns)
                if max_frames and self.stats.frames >= max_frames and (frame_id is None or frame_id > last_id):
                    break
                try:
                    if topic == CAMERA_TOPIC:
                        frame, prepare_ms = self._prepare_frame(rec)  # while the stages work on the last one
                        self._await_reports()
                        self.pacer.wait(stamp)
                        last_id = self._publish_frame(frame, frame_id, stamp, prepare_ms)
                    else:
                        self.pacer.wait(stamp)
                        self._publish_other(rec, topic, frame_id, stamp)
                except DecodeError as exc:  # one bad message in a recording: say which, skip it
                    self.stats.skipped += 1
                    self.health.errors += 1
                    log.warning("skipped a message on %s (log time %d): %s", rec.key, rec.log_time_ns, exc)
            else:
                self._end_of_pass()
                if loop and self.stats.frames:
                    continue
            break
        self._await_reports()
        return self.stats

    def _end_of_pass(self) -> None:
        self.stats.passes += 1
        if self.reader.truncated is not None and not self.stats.truncated:
            self.stats.truncated = str(self.reader.truncated)
            log.warning("%s; replaying the readable part", self.reader.truncated)
        self.renumber.next_pass()

    def _publisher(self, topic: str) -> Publisher:
        pub = self.pubs.get(topic)
        if pub is None:
            pub = self.pubs[topic] = Publisher(self.session, key_for(topic, self.cfg.bus.vehicle))
        return pub

    def _prepare_frame(self, rec: RawRecord) -> tuple[StereoFrame | dict[str, Any], float]:
        """The recorded frame, decoded (or, for ``recorded``, its msgpack map with the images as
        stored), and the milliseconds that took.

        Done before the lockstep wait, so it overlaps the stages' work on the frame before. Decoding
        the bundled recording's JPEG pair and sending it raw cost the replay 12 % of a core, the
        router and the recorder a 1.8 MB frame each (README, Performance).
        """
        start = time.perf_counter()
        as_stored = self.cfg.replay.image_format == RECORDED
        frame = stereo_wire(rec.data) if as_stored else decode(rec.data, StereoFrame)
        return frame, (time.perf_counter() - start) * 1e3

    def _publish_frame(
        self, frame: StereoFrame | dict[str, Any], frame_id: int | None, stamp: int, prepare_ms: float
    ) -> int:
        """Renumber, give a fresh timing trail, publish; returns the frame id sent."""
        start = time.perf_counter()
        if frame_id is None:  # the header peek failed but the message decodes: number it from its body
            own = (frame.frame_id, frame.stamp_ns) if isinstance(frame, StereoFrame) else wire_stamp(frame)
            frame_id, stamp = self.renumber.apply(*own)
        t = now_ns()
        if isinstance(frame, StereoFrame):
            frame = dataclasses.replace(
                frame, frame_id=frame_id, stamp_ns=stamp, timing=[("camera_replay", t, t)],
                image_format=self.cfg.replay.image_format,
            )
            data = encode(frame)
        else:
            frame["body"].update(frame_id=frame_id, stamp_ns=stamp, timing=[["camera_replay", t, t]])
            data = msgpack.packb(frame, use_bin_type=True)
        self._publisher(CAMERA_TOPIC).put(data)
        self.stats.frames += 1
        self.health.frames_out += 1
        self.health.processed(prepare_ms + (time.perf_counter() - start) * 1e3)
        self._in_flight.append(frame_id)
        return frame_id

    def _publish_other(self, rec: RawRecord, topic: str, frame_id: int | None, stamp: int) -> None:
        data = rec.data
        if not self.renumber.identity and frame_id is not None:
            data = encode(dataclasses.replace(decode(data), frame_id=frame_id, stamp_ns=stamp))
        self._publisher(topic).put(data)
        self.stats.other += 1

    def _await_reports(self) -> None:
        """Lockstep: block until every frame sent has its report; a missing one is a timeout."""
        while self.reports is not None and self._in_flight:
            self._await_report(self._in_flight.pop(0))

    def _await_report(self, frame_id: int) -> None:
        timeout = self.cfg.replay.lockstep_timeout_s
        deadline = time.monotonic() + timeout
        while self._done < frame_id and not self.stop.is_set():
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self.stats.lockstep_timeouts += 1
                self.health.last_error = f"lockstep timeout on frame {frame_id}"
                log.warning(
                    "lockstep: no %s for frame %d within %.1f s (%d timeouts so far); going on",
                    self.cfg.replay.lockstep_topic, frame_id, timeout, self.stats.lockstep_timeouts,
                )
                return
            item = self.reports.recv(min(remaining, 0.1))
            if item is not None:
                self._done = max(self._done, item.msg.frame_id)

    def close(self) -> None:
        """Leave the bus, but no sooner than ``bus.close_linger_s`` after the last frame went out.

        A frame put as the replay is stopped is only queued; closing at once can take it from a
        subscriber still busy with the one before (a recorder compressing): the fault test lost
        camera frame 48, published 0.02 s after the stop, while its observer had it (session 47;
        the stages linger the same way since session 17, docs/results/reliability.md).
        """
        linger(list(self.pubs.values()), self.cfg.bus.close_linger_s)
        for pub in self.pubs.values():
            pub.close()
        if self.reports is not None:
            self.reports.close()


def run_replay(
    cfg: Config, session: zenoh.Session, stop: threading.Event, path: Path, loop: bool = False, max_frames: int = 0
) -> ReplayStats:
    """Replay ``path`` until its end (or ``max_frames`` frames, or ``stop``); prints ready and done lines."""
    reader = open_recording(path)
    rc = cfg.replay
    wait = list(rc.wait_for) or (["tracker"] if rc.lockstep else [])
    token = declare_alive(session, "camera_replay", cfg.bus.vehicle)
    replay = Replay(cfg, session, reader, stop)
    try:
        if wait:
            wait_for_services(session, cfg, wait, stop)
        mode = f"lockstep on {rc.lockstep_topic}" if rc.lockstep else ("max" if rc.rate <= 0 else f"rate {rc.rate:g}")
        print(f"camera_replay ready: {path} ({mode}{', loop' if loop else ''})", flush=True)
        health = Publisher(session, key_for("health/camera_replay", cfg.bus.vehicle))
        with HealthReporter(replay.health, health, cfg.health_period_s):
            stats = replay.run(loop, max_frames)
        health.close()
    finally:
        replay.close()
        token.undeclare()
    truncated = f"; TRUNCATED: {stats.truncated}" if stats.truncated else ""
    print(
        f"replay done: {stats.frames} frames, {stats.other} other messages, {stats.passes} passes, "
        f"{stats.lockstep_timeouts} lockstep timeouts, {stats.skipped} skipped{truncated}",
        flush=True,
    )
    return stats


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", type=Path, help="the MCAP file to replay")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--rate", type=float, help="speed factor on the recorded timing (default 1)")
    pace.add_argument("--max", action="store_true", help="as fast as the bus takes it")
    pace.add_argument("--lockstep", action="store_true", help="frame k+1 only after the tracker reported frame k")
    parser.add_argument("--lockstep-on", metavar="TOPIC",
                        help="lockstep on this topic's reports instead, e.g. stereo_depth/points (implies --lockstep)")
    parser.add_argument("--loop", action="store_true", help="start again at the end (frame ids keep increasing)")
    parser.add_argument("--max-frames", type=int, default=0, metavar="N", help="stop after N camera frames")
    parser.add_argument("--keys", help="comma-separated topics to replay "
                        "(default camera/stereo,vehicle/**,groundtruth/**)")
    parser.add_argument("--image-format", choices=REPLAY_FORMATS,
                        help="how images travel (default raw; recorded: as the recording holds them)")
    parser.add_argument("--wait-for", metavar="SERVICE,...", help="liveliness tokens to await before starting")
    add_bus_arguments(parser)


def run(args: argparse.Namespace) -> int:
    keys = [topic_of(k) for k in args.keys.split(",") if k] if args.keys else None
    cfg = config_from_args(
        args,
        {
            "replay.rate": 0.0 if args.max else args.rate,
            "replay.lockstep": True if args.lockstep or args.lockstep_on else None,
            "replay.lockstep_topic": args.lockstep_on,
            "replay.image_format": args.image_format,
            "replay.topics": keys,
            "replay.wait_for": [s for s in args.wait_for.split(",") if s] if args.wait_for else None,
        },
    )
    if cfg.replay.rate < 0:
        raise ConfigError(f"--rate must be positive, got {cfg.replay.rate}")
    open_recording(args.recording)  # a missing or non-MCAP file fails before any network setup
    stop = stop_on_signals()
    with open_session(cfg.bus) as session:
        run_replay(cfg, session, stop, args.recording, args.loop, args.max_frames)
    return 0
