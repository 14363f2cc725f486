"""``stereovox record``: every bus key under ``stereovox/**`` into MCAP, without slowing the pipeline.

The Zenoh callback only copies the payload and stamps the receive time; a writer thread peeks the
capture stamp (a few bytes of the msgpack header, never the images), writes the bytes untouched
and compresses. Between them sits a queue bounded in bytes (``recorder.queue_mb``). When the
disk cannot keep up and the queue is full, the default (``recorder.when_full = "drop"``) drops
the message and counts it in Health, because blocking the Zenoh delivery thread would push back
through BLOCK publishers onto every stage; ``"block"`` makes the recorder lossless for offline
evaluation runs, at the price of slowing the publishers to the disk's pace.

The open chunk is flushed every ``recorder.flush_interval_s``, so SIGKILL loses at most that
chunk; SIGINT/SIGTERM drain the queue and write the summary. Restarted by ``launch`` after a
crash, the recorder continues in ``STEM.restartN.mcap`` beside ``--out`` rather than truncating
the file it was killed writing. An unwritable path or a full disk
stops the recording with an error naming the file; the pipeline, which never waits for the
recorder in ``drop`` mode, runs on.
"""

from __future__ import annotations

import argparse
import collections
import logging
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from common.bus import Publisher, declare_alive, open_session
from common.config import Config
from common.errors import ConfigError, RecordingError
from common.messages import Health, key_for, topic_of
from common.recording import COMPRESSIONS, RecordingWriter, open_recording, peek_stamp
from services.recording_parts import RecordingParts
from services.service_args import add_bus_arguments, config_from_args, stop_on_signals
from services.supervisor import RESTARTS_ENV

log = logging.getLogger(__name__)

Item = tuple[str, bytes, int]  # key, payload, receive time (ns)


class ByteQueue:
    """A FIFO bounded by payload bytes: ``put`` drops (returns False) or waits when it is full."""

    def __init__(self, limit_bytes: int, block: bool) -> None:
        self._items: collections.deque[Item] = collections.deque()
        self._cond = threading.Condition()
        self._limit = limit_bytes
        self._block = block
        self._closed = False
        self.bytes = 0

    def __len__(self) -> int:
        return len(self._items)

    def put(self, item: Item) -> bool:
        size = len(item[1])
        with self._cond:
            while self._items and self.bytes + size > self._limit:  # one oversized item always fits
                if not self._block or self._closed:
                    return False
                self._cond.wait(0.1)
            if self._closed:
                return False
            self._items.append(item)
            self.bytes += size
            self._cond.notify_all()
            return True

    def get(self, timeout_s: float) -> Item | None:
        with self._cond:
            if not self._items:
                self._cond.wait(timeout_s)
            if not self._items:
                return None
            item = self._items.popleft()
            self.bytes -= len(item[1])
            self._cond.notify_all()
            return item

    def close(self) -> None:
        """Refuse everything from now on (the writer has failed)."""
        with self._cond:
            self._closed = True
            self._items.clear()
            self.bytes = 0
            self._cond.notify_all()


@dataclass
class RecorderStats:
    received: int = 0
    written: int = 0
    dropped: int = 0
    bytes_written: int = 0
    callback_s: float = 0.0  # time spent on Zenoh's delivery thread, all messages together


class Recorder:
    """Subscribes to a key expression and writes what arrives from a thread of its own."""

    def __init__(self, session: zenoh.Session, parts: RecordingParts, keys: str, cfg: Config) -> None:
        rc = cfg.recorder
        if rc.when_full not in ("drop", "block"):
            raise ConfigError(f"recorder.when_full must be drop or block, got {rc.when_full!r}")
        self.parts = parts
        self.stats = RecorderStats()
        self.by_topic: dict[str, int] = {}  # messages written per topic, for Health
        self.dropped_by_topic: dict[str, int] = {}
        self.write_ms: collections.deque[float] = collections.deque(maxlen=300)  # recent writes, for p50/p95
        self.error: RecordingError | None = None
        self._queue = ByteQueue(int(rc.queue_mb * 1024 * 1024), block=rc.when_full == "block")
        self._flush_s = rc.flush_interval_s
        self._quiet_s, self._quiet_max_s = rc.stop_quiet_s, rc.stop_quiet_max_s
        self._last_arrival = time.monotonic()
        self._draining = threading.Event()
        self._thread = threading.Thread(target=self._write_loop, name="recorder-writer", daemon=True)
        self._thread.start()
        # On Zenoh's own thread (not zenoh-python's default helper thread, whose queue holds some
        # 256 samples of any size in front of ours): queue_mb is then the real bound, and "block"
        # pushes back on the publishers at once.
        self._sub = session.declare_subscriber(keys, zenoh.handlers.Callback(self._on_sample, indirect=False))

    def _on_sample(self, sample: zenoh.Sample) -> None:
        """The hot path: copy out of Zenoh, stamp, enqueue; nothing is decoded here."""
        start = time.perf_counter()
        received = time.time_ns()
        self._last_arrival = time.monotonic()
        self.stats.received += 1
        key = str(sample.key_expr)
        if not self._queue.put((key, sample.payload.to_bytes(), received)):
            self.stats.dropped += 1
            topic = topic_of(key)
            self.dropped_by_topic[topic] = self.dropped_by_topic.get(topic, 0) + 1
        self.stats.callback_s += time.perf_counter() - start

    def _write_loop(self) -> None:
        next_flush = time.monotonic() + self._flush_s
        try:
            while True:
                item = self._queue.get(timeout_s=0.1)
                if item is not None:
                    key, data, received = item
                    start = time.perf_counter()
                    stamp = peek_stamp(data)
                    self.parts.write(key, data, received, stamp[1] if stamp else received)
                    self.write_ms.append((time.perf_counter() - start) * 1e3)
                    self.stats.written += 1
                    self.stats.bytes_written += len(data)
                    topic = topic_of(key)
                    self.by_topic[topic] = self.by_topic.get(topic, 0) + 1
                elif self._draining.is_set():
                    break
                if time.monotonic() >= next_flush:
                    self.parts.flush()
                    next_flush = time.monotonic() + self._flush_s
            self.parts.close()
        except RecordingError as exc:  # the next part of a split recording could not be opened
            self._fail(exc)
        except OSError as exc:
            self._fail(RecordingError(f"cannot write: {exc.strerror or exc}; recording stopped", str(self.parts.path)))
        except Exception as exc:  # anything else would leave a recorder that silently records nothing
            self._fail(RecordingError(f"writer failed: {type(exc).__name__}: {exc}", str(self.parts.path)))

    def _fail(self, error: RecordingError) -> None:
        self.error = error
        self._queue.close()
        self.parts.abort()

    @property
    def failed(self) -> bool:
        return self.error is not None

    def health_detail(self) -> dict[str, Any]:
        return {
            "bytes": self.stats.bytes_written,
            "queue_depth": len(self._queue),
            "queue_mb": round(self._queue.bytes / 1e6, 3),
            "file": str(self.parts.path),
            "files": len(self.parts.paths),
            "written_by_topic": dict(self.by_topic),
            "dropped_by_topic": dict(self.dropped_by_topic),
            "callback_us_mean": round(1e6 * self.stats.callback_s / max(1, self.stats.received), 1),
        }

    def write_percentiles(self) -> tuple[float, float]:
        """p50 and p95 of the recent per-message write times (ms): compression included."""
        times = np.array(self.write_ms, dtype=np.float64)
        return (float(np.percentile(times, 50)), float(np.percentile(times, 95))) if times.size else (0.0, 0.0)

    def close(self) -> None:
        """Stop receiving once the bus is quiet, write what is queued, finish the file.

        A recorder is stopped after the stages that feed it, but their last messages may still be
        on their way through the router: undeclaring at once would lose them. So it keeps
        listening until nothing has arrived for ``stop_quiet_s`` (at most ``stop_quiet_max_s``).
        """
        started = time.monotonic()
        while not self.failed:
            now = time.monotonic()
            if now - self._last_arrival >= self._quiet_s or now - started >= self._quiet_max_s:
                break
            time.sleep(min(0.05, self._quiet_s))
        self._sub.undeclare()
        self._draining.set()
        self._thread.join()


def _describe(cfg: Config, keys: str, info: dict[str, Any]) -> Any:
    def describe(writer: RecordingWriter, part: int) -> None:
        facts = info | {"recorded_keys": keys, "part": part, "recorded_by": "stereovox record"}
        writer.describe(cfg.to_dict(), facts)

    return describe


def run_recorder(
    cfg: Config,
    session: zenoh.Session,
    stop: threading.Event,
    out: Path,
    keys: str | None = None,
    info: dict[str, Any] | None = None,
) -> RecorderStats:
    """Record until ``stop`` is set; raises :class:`RecordingError` naming the file if writing fails.

    ``info`` becomes each file's ``stereovox.info`` (with the recorder's own facts added): pass
    the replayed recording's facts (``--info-from``) so evaluation of the run knows the source,
    calibration and frame rate. Prints one ``recorder ready`` line once subscribed (tests and
    launchers wait for it) and publishes Health on ``health/recorder`` every ``cfg.health_period_s``.
    """
    rc = cfg.recorder
    keys = keys or rc.keys
    if rc.compression not in COMPRESSIONS:
        raise ConfigError(f"recorder.compression must be one of {sorted(COMPRESSIONS)}, got {rc.compression!r}")
    split_bytes = int(rc.split_size_mb * 1024 * 1024)
    describe = _describe(cfg, keys, info or {})
    parts = RecordingParts(out, rc.compression, rc.chunk_size, split_bytes, rc.split_duration_s, describe)
    recorder = Recorder(session, parts, keys, cfg)
    token = declare_alive(session, "recorder", cfg.bus.vehicle)
    health = Publisher(session, key_for("health/recorder", cfg.bus.vehicle))
    print(f"recorder ready: {keys} -> {parts.path}", flush=True)
    started = time.monotonic()
    last_bytes, last_t, reports = 0, started, 0
    try:
        while not stop.wait(cfg.health_period_s) and not recorder.failed:
            now, done = time.monotonic(), recorder.stats.bytes_written
            detail = recorder.health_detail() | {"mb_per_s": round((done - last_bytes) / 1e6 / (now - last_t), 3)}
            last_bytes, last_t, reports = done, now, reports + 1
            s = recorder.stats
            p50, p95 = recorder.write_percentiles()
            health.put(
                Health(
                    frame_id=reports, stamp_ns=time.time_ns(), service="recorder", frames_in=s.received,
                    frames_out=s.written, dropped=s.dropped, uptime_s=now - started, detail=detail,
                    p50_ms=round(p50, 3), p95_ms=round(p95, 3),
                )
            )
    finally:
        recorder.close()
        token.undeclare()
        health.close()
    if recorder.error is not None:
        raise recorder.error
    s = recorder.stats
    print(
        f"recorder done: {s.written} messages, {s.bytes_written / 1e6:.1f} MB, {s.dropped} dropped, "
        f"files: {', '.join(str(p) for p in parts.paths)}",
        flush=True,
    )
    return s


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, type=Path, help="the MCAP file (FILE_0.mcap, ... when splitting)")
    parser.add_argument("--keys", help="key expression to record (default recorder.keys: stereovox/**)")
    parser.add_argument("--compression", choices=sorted(COMPRESSIONS), help="chunk compression (default zstd)")
    parser.add_argument("--split-size", type=float, metavar="MB", help="start a new file after this many MB")
    parser.add_argument("--split-duration", type=float, metavar="S", help="start a new file after this many seconds")
    parser.add_argument("--when-full", choices=("drop", "block"), help="queue full: drop and count, or push back")
    parser.add_argument("--info-from", type=Path, metavar="RECORDING",
                        help="copy this recording's facts (source, calib, frame rate...) into the metadata")
    add_bus_arguments(parser)


def run(args: argparse.Namespace) -> int:
    cfg = config_from_args(
        args,
        {
            "recorder.compression": args.compression,
            "recorder.split_size_mb": args.split_size,
            "recorder.split_duration_s": args.split_duration,
            "recorder.when_full": args.when_full,
            "recorder.keys": args.keys,
        },
    )
    info = open_recording(args.info_from).info() if args.info_from else None
    stop = stop_on_signals()
    with open_session(cfg.bus) as session:
        run_recorder(cfg, session, stop, restarted_path(args.out, os.environ.get(RESTARTS_ENV, "")), info=info)
    return 0


def restarted_path(out: Path, restarts: str) -> Path:
    """``run.mcap`` for the first start, ``run.restart1.mcap`` ... after restarts by ``launch``.

    The file of a killed recorder is complete up to its last flushed chunk; opening the same
    name again would truncate it, so each restart records into a file of its own beside it.
    """
    count = int(restarts) if restarts.isdigit() else 0
    return out.with_name(f"{out.stem}.restart{count}{out.suffix}") if count else out
