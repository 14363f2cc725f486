"""The one bus shell every stage runs in: inputs in, the pure core called, outputs out, health reported.

A stage is described by a :class:`Stage` — its name, the topics it reads (in the order its core
takes them) and writes, the core call, and what it publishes for a frame the core failed on.
:func:`run_stage` then does the same for every service:

1. subscribe to each input with the queue policy the launch spec names — ``newest`` for a live
   run (a stage that falls behind processes the newest frame and counts the ones it skipped),
   ``fifo`` for lockstep replay (a bounded queue that pushes back on the producer);
2. pair the inputs of one frame by ``frame_id`` (:class:`services.join.FrameJoiner`);
3. call the core, stamp each output's timing trail (union of the inputs' trails + this stage);
4. publish exactly one set of outputs per frame — when the core raises, the stage's *empty*
   outputs for that frame id, so a lockstep replay waiting on frame k never waits forever;
5. declare a liveliness token and publish Health once a second until ``stop`` is set; before it,
   ``warm`` puts a few made-up frames through a throwaway core (services/warmup.py), so that a
   stage is alive only once its compiled code is loaded.

Every wait has a timeout so SIGINT/SIGTERM (which only set ``stop``) end the loop promptly.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import zenoh

from common.bus import Publisher, declare_alive, linger, subscribe
from common.config import Config
from common.messages import Message, key_for, now_ns, stamp_output
from services.health import HealthReporter, StageHealth
from services.join import FrameJoiner

log = logging.getLogger(__name__)

#: how long the loop sleeps at most before it looks at ``stop`` again.
POLL_S: float = 0.1


def _never_degenerate() -> bool:
    return False


def _no_detail() -> dict[str, Any]:
    return {}


def _cold() -> None:
    return None


@dataclass(frozen=True)
class Stage:
    """What makes one service; ``process`` and ``empty`` take the inputs in ``inputs`` order."""

    name: str
    inputs: dict[str, type[Message]]  # topic -> message type
    outputs: tuple[str, ...]  # topics, in the order process() returns its messages
    process: Callable[..., Sequence[Message]]
    empty: Callable[..., Sequence[Message]]  # outputs for a frame the core failed on
    degenerate: Callable[[], bool] = field(default=_never_degenerate)  # did the last frame degrade?
    counters: Callable[[], dict[str, Any]] = field(default=_no_detail)  # the core's own counts, for Health
    optional: tuple[str, ...] = ()  # inputs taken when there, never waited for (services/join.py); None if not
    warm: Callable[[], object] = field(default=_cold)  # run once before the stage is alive (services/warmup.py)


class _Throttle:
    """True at most once per ``period_s``: errors on every frame must not flood the log."""

    def __init__(self, period_s: float = 1.0) -> None:
        self.period_s = period_s
        self._last = -float("inf")

    def __call__(self) -> bool:
        now = time.monotonic()
        if now - self._last >= self.period_s:
            self._last = now
            return True
        return False


class StageLoop:
    """The receive -> join -> process -> publish loop of one stage on an open session."""

    def __init__(
        self, stage: Stage, cfg: Config, session: zenoh.Session, policy: str = "newest", depth: int = 8
    ) -> None:
        vehicle = cfg.bus.vehicle
        self.stage = stage
        self.policy = policy
        self.depth = depth
        self._wake = threading.Event()
        self.subs = {
            topic: subscribe(session, key_for(topic, vehicle), kind, policy, depth, self._wake)
            for topic, kind in stage.inputs.items()
        }
        self.pubs = [Publisher(session, key_for(topic, vehicle)) for topic in stage.outputs]
        self.joiner = FrameJoiner(list(stage.inputs), capacity=4 * depth, optional=stage.optional)
        self.health = StageHealth(stage.name, list(self.subs.values()))
        self.health.extra["join_evicted"] = lambda: self.joiner.evicted
        self.health.extra["join_pending"] = self.joiner.pending
        if stage.optional:
            self.health.extra["join_without_optional"] = lambda: self.joiner.without_optional
        self.health.extra["policy"] = lambda: self.policy
        self.health.extra["core"] = stage.counters
        self._ready: deque[dict[str, Message]] = deque()
        self._error_log = _Throttle()

    def step(self, timeout_s: float = POLL_S) -> bool:
        """Take what has arrived, process at most one complete frame; False if there was none."""
        if not self._ready:
            self._wake.wait(timeout_s)
            self._wake.clear()
        self._take_inputs()
        if not self._ready:
            return False
        if self.policy == "newest":
            while len(self._ready) > 1:  # a newer frame is complete: skip the older ones
                self._ready.popleft()
                self.health.superseded += 1
        self._process(self._ready.popleft())
        return True

    def _take_inputs(self) -> None:
        for topic, sub in self.subs.items():
            # fifo: leave what the stage cannot take yet in the subscriber, so it pushes back upstream
            while self.policy == "newest" or len(self._ready) < self.depth:
                item = sub.recv(0)
                if item is None:
                    break
                frame = self.joiner.add(topic, item.msg)
                if frame is not None:
                    self._ready.append(frame)

    def _process(self, frame: dict[str, Message]) -> None:
        inputs = [frame.get(topic) for topic in self.stage.inputs]  # None: an optional input not there
        present = [m for m in inputs if m is not None]
        start_ns, t0 = now_ns(), time.perf_counter()
        try:
            outputs = self.stage.process(*inputs)
            if self.stage.degenerate():
                self.health.degenerate += 1
        except Exception as exc:  # any core failure on one frame: count it, publish empty, go on
            outputs = self._failed(inputs, present[0].frame_id, exc)
            if outputs is None:
                return
        stamped = [stamp_output(out, present, self.stage.name, start_ns) for out in outputs]
        for pub, out in zip(self.pubs, stamped, strict=True):
            pub.put(out)
        self.health.frames_out += 1
        self.health.processed((time.perf_counter() - t0) * 1e3)

    def _failed(self, inputs: list[Message | None], frame_id: int, exc: Exception) -> Sequence[Message] | None:
        self.health.errors += 1
        self.health.last_error = f"frame {frame_id}: {type(exc).__name__}: {exc}"
        if self._error_log():
            log.error(
                "%s failed on %s (%d errors so far); publishing empty outputs",
                self.stage.name, self.health.last_error, self.health.errors, exc_info=exc,
            )
        try:
            return self.stage.empty(*inputs)
        except Exception as empty_exc:  # the inputs are too broken to even describe an empty frame
            log.error("%s: no empty output for frame %d: %s", self.stage.name, frame_id, empty_exc)
            return None

    def close(self) -> None:
        for sub in self.subs.values():
            sub.close()
        for pub in self.pubs:
            pub.close()


def run_stage(
    stage: Stage,
    cfg: Config,
    session: zenoh.Session,
    stop: threading.Event,
    policy: str = "newest",
    depth: int = 8,
    max_frames: int = 0,
) -> StageHealth:
    """Run ``stage`` on ``session`` until ``stop`` is set (or ``max_frames`` are out); returns its counters."""
    vehicle = cfg.bus.vehicle
    loop = StageLoop(stage, cfg, session, policy, depth)
    stage.warm()  # subscribed already: what arrives meanwhile waits in the queues (a restart mid-run)
    health_pub = Publisher(session, key_for(f"health/{stage.name}", vehicle))
    token = declare_alive(session, stage.name, vehicle)
    try:
        with HealthReporter(loop.health, health_pub, cfg.health_period_s):
            log.info(
                "%s ready: %s -> %s (policy %s, vehicle %s)",
                stage.name, ", ".join(stage.inputs), ", ".join(stage.outputs), policy, vehicle,
            )
            while not stop.is_set() and not 0 < max_frames <= loop.health.frames_out:
                loop.step()
    finally:
        token.undeclare()
        linger(loop.pubs, cfg.bus.close_linger_s)
        loop.close()
        health_pub.close()
    h = loop.health
    log.info("%s stopped: %d frames out, %d errors, %d dropped", stage.name, h.frames_out, h.errors, h.report().dropped)
    return h

