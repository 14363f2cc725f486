"""The Zenoh bus: sessions from one configuration, publishers, subscribers with explicit flow control.

Choices measured on this machine (FACTS.md): the default DROP congestion control lost 12-17 % of
messages under load, so frames are published with BLOCK; the default subscriber FIFO holds 256
samples and lets a slow consumer fall ever further behind, so live inputs keep only the newest
frame (and count what they replace), while lockstep consumers use a small bounded FIFO that
pushes back on the producer. Blocking ``recv()`` swallows Ctrl-C, so every wait here has a timeout.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

import zenoh

from common.codec import decode, encode
from common.config import BusConfig
from common.errors import BusError, DecodeError
from common.messages import Message, key_for

log = logging.getLogger(__name__)

M = TypeVar("M", bound=Message)


def zenoh_config(bus: BusConfig) -> zenoh.Config:
    """A Zenoh configuration from the bus section: explicit endpoints, scouting off by default."""
    conf = zenoh.Config.from_file(bus.zenoh_config) if bus.zenoh_config else zenoh.Config()
    if bus.mode not in ("peer", "client", "router"):
        raise BusError(f"bus.mode must be peer, client or router, got {bus.mode!r}")
    conf.insert_json5("mode", json.dumps(bus.mode))
    # A peer listens on every interface unless told otherwise: default to an ephemeral loopback port.
    listen = bus.listen or (["tcp/127.0.0.1:0"] if bus.mode != "client" else [])
    conf.insert_json5("listen/endpoints", json.dumps(listen))
    if bus.connect:
        conf.insert_json5("connect/endpoints", json.dumps(bus.connect))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(bus.multicast_scouting))
    if not bus.zenoh_config:  # a deployment's Zenoh file decides for itself (deploy/zenoh/*.json5)
        conf.insert_json5("transport/shared_memory/enabled", json.dumps(bus.shared_memory))
    if bus.user:
        conf.insert_json5("transport/auth/usrpwd/user", json.dumps(bus.user))
        conf.insert_json5("transport/auth/usrpwd/password", json.dumps(bus.password))
    return conf


def open_session(bus: BusConfig) -> zenoh.Session:
    """Open a session (a context manager); errors become :class:`BusError` naming the endpoints."""
    try:
        return zenoh.open(zenoh_config(bus))
    except zenoh.ZError as exc:
        raise BusError(
            f"cannot open a Zenoh {bus.mode} session (listen {bus.listen}, connect {bus.connect}): {exc}"
        ) from None


class Publisher:
    """Publishes messages on one key; BLOCK congestion control so frames are not silently lost."""

    def __init__(self, session: zenoh.Session, key: str, block: bool = True) -> None:
        self.key = key
        congestion = zenoh.CongestionControl.BLOCK if block else zenoh.CongestionControl.DROP
        self._pub = session.declare_publisher(key, congestion_control=congestion)
        self.sent = 0
        self.last_put = float("-inf")  # time.monotonic() of the latest put

    def put(self, msg: Message | bytes) -> None:
        payload = encode(msg) if isinstance(msg, Message) else bytes(msg)
        self._pub.put(payload)
        self.sent += 1
        self.last_put = time.monotonic()

    def matched(self) -> bool:
        """Whether some subscriber is reachable on this key now (a source waits for this before sending)."""
        return bool(self._pub.matching_status.matching)

    def close(self) -> None:
        self._pub.undeclare()


def linger(publishers: list[Publisher], seconds: float) -> float:
    """Stay on the bus until ``seconds`` after the latest put of any of ``publishers``; the wait (s).

    A put returns once Zenoh has queued the message, not once the router has passed it on. A
    session closed right after it can take its last messages with it: in a loopback test (a 2 MB
    message 40 times, one subscriber 0.3 s slow a message; scripts/close_loss.py) the last 1-6
    were lost to both subscribers in 4 of 29 runs, and none in 27 runs that stayed 0.5 s. A stage
    stopped mid-frame publishes that frame and leaves, so the recorder could miss it
    (docs/results/reliability.md, "A stage's last message at a stop").
    """
    latest = max((p.last_put for p in publishers), default=float("-inf"))
    wait = max(0.0, seconds - (time.monotonic() - latest))
    if wait > 0.0:
        time.sleep(wait)
    return wait


@dataclass
class Received(Generic[M]):
    """A decoded message with the key it came on and when it arrived (wall clock ns)."""

    key: str
    msg: M
    received_ns: int


class _Subscriber(ABC, Generic[M]):
    """Common part: decode in the Zenoh callback, count bad payloads, hand good ones to a buffer.

    A full FIFO blocks that callback and so the session's delivery: a slow consumer slows its
    sender instead of queueing without bound. The stage loop drains every input into its joiner,
    so one full input never starves another of the same process for long.
    """

    def __init__(
        self, session: zenoh.Session, key: str, expected: type[M] | None, wakeup: threading.Event | None = None
    ) -> None:
        self.key = key
        self.expected = expected
        self.received = 0
        self.dropped = 0
        self.decode_errors = 0
        self.last_error = ""
        self._last_log = 0.0
        #: set after every delivered message, so one thread can wait on several subscribers at once.
        self.wakeup = wakeup
        self._closed = threading.Event()
        # Called on Zenoh's own delivery thread (indirect=False). The default hands samples to a
        # helper thread through a ~256-message queue, which for camera frames is ~470 MB sitting in
        # front of a FIFO of 8 before any back-pressure reaches the sender (docs/results/reliability.md).
        self._sub = session.declare_subscriber(key, zenoh.handlers.Callback(self._on_sample, indirect=False))

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            msg = decode(sample.payload.to_bytes(), self.expected)
        except DecodeError as exc:
            self.decode_errors += 1
            self.last_error = str(exc)
            now = time.monotonic()
            if now - self._last_log >= 1.0:  # at most one log line a second per subscriber
                self._last_log = now
                log.warning(
                    "dropped a malformed message on %s: %s (%d so far)", sample.key_expr, exc, self.decode_errors
                )
            return
        self.received += 1
        self._push(Received(str(sample.key_expr), msg, time.time_ns()))
        if self.wakeup is not None:
            self.wakeup.set()

    @abstractmethod
    def _push(self, item: Received[M]) -> None:
        """Hand a decoded message to the buffer (called on Zenoh's delivery thread)."""

    def close(self) -> None:
        self._closed.set()
        self._sub.undeclare()


class LatestSubscriber(_Subscriber[M]):
    """Keeps only the newest message; every message replaced before it was taken counts as dropped."""

    def __init__(
        self,
        session: zenoh.Session,
        key: str,
        expected: type[M] | None = None,
        wakeup: threading.Event | None = None,
    ) -> None:
        self._slot: Received[M] | None = None
        self._cond = threading.Condition()
        super().__init__(session, key, expected, wakeup)

    def _push(self, item: Received[M]) -> None:
        with self._cond:
            if self._slot is not None:
                self.dropped += 1
            self._slot = item
            self._cond.notify()

    def recv(self, timeout_s: float) -> Received[M] | None:
        """The newest message, waiting at most ``timeout_s``; None if nothing came."""
        with self._cond:
            if self._slot is None:
                self._cond.wait(timeout_s)
            item, self._slot = self._slot, None
            return item


class FifoSubscriber(_Subscriber[M]):
    """A bounded FIFO: when full, the Zenoh delivery thread waits, pushing back on the publisher."""

    def __init__(
        self,
        session: zenoh.Session,
        key: str,
        expected: type[M] | None = None,
        depth: int = 8,
        wakeup: threading.Event | None = None,
    ) -> None:
        self._queue: queue.Queue[Received[M]] = queue.Queue(maxsize=depth)
        super().__init__(session, key, expected, wakeup)

    def _push(self, item: Received[M]) -> None:
        # Wait in slices so a consumer that has stopped (closed) never leaves Zenoh's thread stuck.
        while not self._closed.is_set():
            try:
                self._queue.put(item, timeout=0.1)
                return
            except queue.Full:
                continue
        self.dropped += 1

    def pending(self) -> int:
        """Messages waiting in the FIFO."""
        return self._queue.qsize()

    def recv(self, timeout_s: float) -> Received[M] | None:
        try:
            return self._queue.get(timeout=timeout_s)
        except queue.Empty:
            return None


QUEUE_POLICIES: tuple[str, ...] = ("newest", "fifo")


def subscribe(
    session: zenoh.Session,
    key: str,
    expected: type[M] | None = None,
    policy: str = "newest",
    depth: int = 8,
    wakeup: threading.Event | None = None,
) -> LatestSubscriber[M] | FifoSubscriber[M]:
    """A subscriber with the queue policy a launch spec names: ``newest`` or ``fifo``.

    ``wakeup`` (optional) is set after each delivered message: a loop reading several inputs waits
    on that one event instead of polling each subscriber in turn.
    """
    if policy == "newest":
        return LatestSubscriber(session, key, expected, wakeup)
    if policy == "fifo":
        return FifoSubscriber(session, key, expected, depth, wakeup)
    raise BusError(f"queue policy must be newest or fifo, got {policy!r}")


def liveliness_key(service: str, vehicle: str) -> str:
    return key_for(f"alive/{service}", vehicle)


def declare_alive(session: zenoh.Session, service: str, vehicle: str) -> zenoh.LivelinessToken:
    """Announce that a service is up; the token vanishes when the process or its session ends."""
    return session.liveliness().declare_token(liveliness_key(service, vehicle))


def watch_alive(session: zenoh.Session, vehicle: str, on_change: Callable[[str, bool], None]) -> zenoh.Subscriber:
    """Call ``on_change(service, alive)`` for every service's liveliness, current ones included."""

    def handler(sample: zenoh.Sample) -> None:
        service = str(sample.key_expr).rsplit("/", 1)[-1]
        on_change(service, sample.kind == zenoh.SampleKind.PUT)

    return session.liveliness().declare_subscriber(liveliness_key("*", vehicle), handler, history=True)

