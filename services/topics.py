"""``stereovox topics list | echo KEY | hz KEY``: look at the bus from any computer, read-only.

As ``ros2 topic`` does: ``list`` shows the keys heard within a short window (with schema, count
and rate) and the services whose liveliness tokens are up; ``echo`` prints each decoded message
on one line, arrays shown as dtype and shape; ``hz`` prints the arrival rate once a second.
``--count N`` and ``--duration S`` make each end on its own (scripts, tests). KEY is a topic
(``camera/stereo``, under ``stereovox/<vehicle>/``) or a full key expression, wildcards allowed.
"""

from __future__ import annotations

import argparse
import dataclasses
import queue
import threading
import time
from typing import Any

import msgpack
import numpy as np
import zenoh

from common.bus import open_session
from common.codec import decode
from common.errors import ConfigError, DecodeError
from common.messages import DEFAULT_VEHICLE, key_for
from services.runner import add_bus_arguments, bus_config, stop_on_signals

#: how long ``list`` listens when no --duration is given.
LIST_WINDOW_S: float = 2.0
#: longest line ``echo`` prints.
MAX_LINE: int = 400


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("action", choices=("list", "echo", "hz"))
    parser.add_argument("key", nargs="?", help="topic (camera/stereo) or key expression (stereovox/**)")
    add_bus_arguments(parser)
    parser.add_argument("--vehicle", default=DEFAULT_VEHICLE, help="vehicle name in the keys (default ego)")
    parser.add_argument("--count", type=int, default=0, help="stop after N messages")
    parser.add_argument("--duration", type=float, default=0.0, help="stop after S seconds")


def resolve_key(key: str, vehicle: str) -> str:
    """A topic becomes ``stereovox/<vehicle>/<topic>``; a full key expression stays as it is."""
    return key if key.startswith("stereovox/") else key_for(key, vehicle)


def summarise(value: Any, depth: int = 0) -> str:
    """One compact line for a decoded value: arrays as dtype[shape], long lists as counts."""
    if isinstance(value, np.ndarray):
        if value.size <= 4 and value.ndim <= 1:
            return np.array2string(value, precision=3, separator=",")
        return f"{value.dtype}[{'x'.join(str(d) for d in value.shape)}]"
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        if depth >= 2:
            return type(value).__name__
        inner = " ".join(
            f"{f.name}={_trail(value.timing) if f.name == 'timing' else summarise(getattr(value, f.name), depth + 1)}"
            for f in dataclasses.fields(value)
        )
        return f"{type(value).__name__}({inner})" if depth else inner
    if isinstance(value, (list, tuple)):
        if len(value) > 3:
            kinds = sorted({type(v).__name__ for v in value})
            return f"[{len(value)} x {'/'.join(kinds)}]"
        return "[" + ", ".join(summarise(v, depth + 1) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {summarise(v, depth + 1)}" for k, v in value.items()) + "}"
    if isinstance(value, float):
        return f"{value:.4g}"
    return repr(value)


def _trail(timing: list[tuple[str, int, int]]) -> str:
    """A timing trail as each stage's duration: ``[camera_replay 0.0ms, stereo_depth 84.2ms]``."""
    return "[" + ", ".join(f"{stage} {(end - start) / 1e6:.1f}ms" for stage, start, end in timing) + "]"


def schema_of(payload: bytes) -> str:
    """``stereovox.<Schema>/<v>`` from a payload's envelope, or why it is not one."""
    try:
        envelope = msgpack.unpackb(payload, raw=False)
        return f"stereovox.{envelope['schema']}/{envelope['v']}"
    except Exception:  # any undecodable payload is shown, not fatal
        return "<not a stereovox message>"


class _Tap:
    """Samples of one key expression handed from Zenoh's thread to the main loop.

    ``echo`` needs the payloads, so few are queued (camera frames are megabytes each); ``hz``
    keeps only arrival times, so it can queue many and still count a fast key.
    """

    def __init__(self, session: zenoh.Session, key: str, keep_payload: bool = True) -> None:
        self.keep_payload = keep_payload
        self.samples: queue.Queue[tuple[str, bytes, float]] = queue.Queue(maxsize=32 if keep_payload else 65536)
        self.skipped = 0
        self._sub = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        payload = sample.payload.to_bytes() if self.keep_payload else b""
        try:
            self.samples.put_nowait((str(sample.key_expr), payload, time.monotonic()))
        except queue.Full:  # a terminal cannot keep up with a firehose: count what it skips
            self.skipped += 1

    def each(self, stop: threading.Event, count: int, duration: float) -> Any:
        """Yield samples until ``count`` were seen, ``duration`` passed or ``stop`` was set."""
        end = time.monotonic() + duration if duration > 0 else float("inf")
        seen = 0
        while not stop.is_set() and time.monotonic() < end and (count <= 0 or seen < count):
            try:
                item = self.samples.get(timeout=min(0.1, max(0.0, end - time.monotonic())))
            except queue.Empty:
                continue
            seen += 1
            yield item

    def close(self) -> None:
        self._sub.undeclare()


def list_keys(session: zenoh.Session, stop: threading.Event, duration: float) -> None:
    """Count every key heard for ``duration`` seconds (in Zenoh's thread: nothing queued), then print."""
    alive: dict[str, bool] = {}
    seen: dict[str, list[Any]] = {}  # key -> [schema, count, first, last]
    lock = threading.Lock()

    def on_token(sample: zenoh.Sample) -> None:
        alive[str(sample.key_expr)] = sample.kind == zenoh.SampleKind.PUT

    def on_sample(sample: zenoh.Sample) -> None:
        key, t = str(sample.key_expr), time.monotonic()
        with lock:
            if key not in seen:
                seen[key] = [schema_of(sample.payload.to_bytes()), 0, t, t]
            entry = seen[key]
            entry[1] += 1
            entry[3] = t

    tokens = session.liveliness().declare_subscriber("stereovox/*/alive/*", on_token, history=True)
    sub = session.declare_subscriber("stereovox/**", on_sample)
    stop.wait(duration or LIST_WINDOW_S)
    sub.undeclare()
    tokens.undeclare()
    width = max([len(k) for k in seen] + [3])
    print(f"{'KEY':<{width}}  {'SCHEMA':<28} {'MSGS':>6} {'HZ':>8}")
    for key in sorted(seen):
        schema, n, first, last = seen[key]
        rate = (n - 1) / (last - first) if n > 1 and last > first else 0.0
        print(f"{key:<{width}}  {schema:<28} {n:>6} {rate:>8.2f}")
    up = sorted(k for k, on in alive.items() if on)
    print(f"alive ({len(up)}): " + (", ".join(up) if up else "none"), flush=True)


def echo(tap: _Tap, stop: threading.Event, count: int, duration: float) -> None:
    for key, payload, _ in tap.each(stop, count, duration):
        try:
            msg = decode(payload)
            line = f"{key} {msg.schema_id()} {summarise(msg)}"
        except DecodeError as exc:
            line = f"{key} <undecodable: {exc}>"
        print(line if len(line) <= MAX_LINE else line[: MAX_LINE - 3] + "...", flush=True)


def hz(tap: _Tap, stop: threading.Event, count: int, duration: float) -> None:
    arrivals: list[float] = []
    window_start = time.monotonic()
    for _, _, t in tap.each(stop, count, duration):
        arrivals.append(t)
        if t - window_start >= 1.0 and len(arrivals) > 1:
            window_start = t
            gaps = np.diff(arrivals[-1000:])
            print(f"rate {1.0 / gaps.mean():.2f} Hz  min {gaps.min():.4f} s  max {gaps.max():.4f} s  "
                  f"std {gaps.std():.4f} s  window {len(gaps) + 1}", flush=True)
    if tap.skipped:
        print(f"(skipped {tap.skipped} messages that arrived faster than they could be counted)", flush=True)
    if len(arrivals) > 1:
        span = arrivals[-1] - arrivals[0]
        print(f"average rate {(len(arrivals) - 1) / span:.2f} Hz over {len(arrivals)} messages", flush=True)
    else:
        print(f"average rate: not enough messages ({len(arrivals)})", flush=True)


def run(args: argparse.Namespace) -> int:
    if args.action != "list" and not args.key:
        raise ConfigError(f"topics {args.action} needs a KEY (a topic like camera/stereo or a key expression)")
    cfg = bus_config(args)
    cfg.bus.vehicle = args.vehicle
    stop = stop_on_signals()
    with open_session(cfg.bus) as session:
        if args.action == "list":
            list_keys(session, stop, args.duration)
            return 0
        tap = _Tap(session, resolve_key(args.key, args.vehicle), keep_payload=args.action == "echo")
        try:
            (echo if args.action == "echo" else hz)(tap, stop, args.count, args.duration)
        finally:
            tap.close()
    return 0
