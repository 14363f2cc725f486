"""What a service reports once a second on ``health/<service>``: counts, drops, errors and speed.

Counts come from two places: the subscribers (received, dropped by the newest-frame policy,
decode errors — counted on Zenoh's delivery thread) and the stage loop (frames out, core errors,
superseded joined frames, processing times). The report is built on a timer thread while the
loop runs, so the loop never stops to report and a slow core still reports on time.

``frames_in`` counts messages over all inputs (a joining stage receives two per frame);
``p50_ms``/``p95_ms`` are per frame handled: the core, stamping and publishing its outputs —
what decides the rate a stage can keep up with.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from common.bus import FifoSubscriber, LatestSubscriber, Publisher
from common.messages import Health, now_ns

#: processing times kept for the percentiles: about the last ten seconds at 30 Hz.
WINDOW: int = 300


class StageHealth:
    """Counters of one service, thread-safe enough for one writer and one reporting thread."""

    def __init__(self, service: str, subscribers: Sequence[LatestSubscriber[Any] | FifoSubscriber[Any]] = ()) -> None:
        self.service = service
        self.subscribers = list(subscribers)
        self.started = time.monotonic()
        self.frames_out = 0
        self.errors = 0
        self.superseded = 0  # complete frames skipped because a newer one was ready (newest policy)
        self.degenerate = 0
        self.last_error = ""
        self.reports = 0
        self.extra: dict[str, Callable[[], Any]] = {}  # more detail, read when reporting
        self._times_ms: deque[float] = deque(maxlen=WINDOW)
        self._lock = threading.Lock()

    def processed(self, elapsed_ms: float) -> None:
        with self._lock:
            self._times_ms.append(elapsed_ms)

    def report(self) -> Health:
        """A Health message with the counts so far and p50/p95 over the recent window."""
        with self._lock:
            times = np.array(self._times_ms, dtype=np.float64)
        p50, p95 = (float(v) for v in np.percentile(times, [50, 95])) if times.size else (0.0, 0.0)
        subs = self.subscribers
        detail: dict[str, Any] = {
            "degenerate": self.degenerate,
            "superseded": self.superseded,
            "last_error": self.last_error,
            "inputs": {
                s.key: {"received": s.received, "dropped": s.dropped, "decode_errors": s.decode_errors}
                for s in subs
            },
        }
        detail.update({name: get() for name, get in self.extra.items()})
        self.reports += 1
        return Health(
            frame_id=self.reports,
            stamp_ns=now_ns(),
            service=self.service,
            frames_in=sum(s.received for s in subs),
            frames_out=self.frames_out,
            dropped=sum(s.dropped for s in subs) + self.superseded,
            decode_errors=sum(s.decode_errors for s in subs),
            errors=self.errors,
            p50_ms=round(p50, 3),
            p95_ms=round(p95, 3),
            uptime_s=round(time.monotonic() - self.started, 3),
            detail=detail,
        )


class HealthReporter:
    """Publishes ``health.report()`` every ``period_s`` on a daemon thread until stopped."""

    def __init__(self, health: StageHealth, publisher: Publisher, period_s: float = 1.0) -> None:
        self.health = health
        self.publisher = publisher
        self.period_s = period_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name=f"health-{health.service}", daemon=True)

    def __enter__(self) -> HealthReporter:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.publisher.put(self.health.report())  # a last report, so a clean stop is visible

    def _loop(self) -> None:
        while not self._stop.wait(self.period_s):
            self.publisher.put(self.health.report())
