"""``stereovox monitor``: watch a running vehicle from any computer, without touching it.

The monitor joins the bus as a Zenoh client (``--connect tcp/HOST:PORT``) and declares only
subscribers and a liveliness subscriber, never a publisher, so it can run on a laptop next to a
vehicle whose router denies it every ``put``. It shows each service alive or gone (liveliness
tokens), its rate, latency p50/p95, drops and decode errors (its Health reports), and the
current obstacles (tracker output): a rich Live dashboard, or one snapshot with ``--once`` for
scripts and tests. ``--foxglove`` serves the same vehicle to the Foxglove app instead.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from collections.abc import Callable

import numpy as np
import zenoh
from rich.console import Console, Group
from rich.table import Table
from rich.text import Text

from common import messages as sv
from common.bus import FifoSubscriber, LatestSubscriber, open_session, subscribe, watch_alive
from common.geometry import invert, transform
from services.runner import add_bus_arguments, bus_config, stop_on_signals


class VehicleView:
    """What the monitor knows of one vehicle; written by Zenoh's threads, read by the screen."""

    def __init__(self) -> None:
        self.alive: dict[str, bool] = {}
        self.health: dict[str, sv.Health] = {}
        self.rate_hz: dict[str, float] = {}
        self.obstacles: sv.Obstacles | None = None
        self.heard: dict[str, float] = {}  # service (or "tracker/obstacles") -> monotonic time last heard
        self.obstacle_messages = 0
        self._lock = threading.Lock()

    def on_alive(self, service: str, alive: bool) -> None:
        with self._lock:
            self.alive[service] = alive

    def on_health(self, report: sv.Health) -> None:
        """Keep the newest report; the rate is frames out per second of uptime since the last one."""
        with self._lock:
            last = self.health.get(report.service)
            if last is not None and report.uptime_s > last.uptime_s:
                self.rate_hz[report.service] = (report.frames_out - last.frames_out) / (report.uptime_s - last.uptime_s)
            elif report.uptime_s > 0:
                self.rate_hz[report.service] = report.frames_out / report.uptime_s
            self.health[report.service] = report
            self.heard[report.service] = time.monotonic()

    def on_obstacles(self, msg: sv.Obstacles) -> None:
        with self._lock:
            self.obstacles = msg
            self.heard["tracker/obstacles"] = time.monotonic()
            self.obstacle_messages += 1

    def missing(self) -> list[str]:
        """What a complete snapshot still lacks (empty when one can be printed)."""
        with self._lock:
            up = [s for s, on in self.alive.items() if on]
            lacking = [] if up else ["a liveliness token"]
            lacking += [f"health of {s}" for s in up if s not in self.health]
            if self.obstacles is None:
                lacking.append("an Obstacles message")
            return lacking

    def has_obstacle(self) -> bool:
        with self._lock:
            return self.obstacles is not None and bool(self.obstacles.obstacles)

    def _age(self, what: str) -> str:
        """Seconds since ``what`` was last heard: a stalled service shows a growing age before it is gone."""
        return f"{time.monotonic() - self.heard[what]:.1f}" if what in self.heard else "-"

    def services_table(self) -> Table:
        table = Table(title="services", title_justify="left", expand=False)
        for name, justify in (("service", "left"), ("status", "left"), ("rate Hz", "right"), ("p50 ms", "right"),
                              ("p95 ms", "right"), ("in", "right"), ("out", "right"), ("dropped", "right"),
                              ("decode err", "right"), ("errors", "right"), ("report age s", "right")):
            table.add_column(name, justify=justify)  # type: ignore[arg-type]
        with self._lock:
            for service in sorted(set(self.alive) | set(self.health)):
                status = _status(self.alive.get(service))
                h = self.health.get(service)
                if h is None:
                    table.add_row(service, status, *["-"] * 9)
                    continue
                table.add_row(
                    service, status, f"{self.rate_hz.get(service, 0.0):.2f}", f"{h.p50_ms:.1f}", f"{h.p95_ms:.1f}",
                    str(h.frames_in), str(h.frames_out), str(h.dropped), str(h.decode_errors), str(h.errors),
                    self._age(service),
                )
        return table

    def obstacles_table(self) -> Table:
        with self._lock:
            msg = self.obstacles
        title = "obstacles (none received yet)" if msg is None else (
            f"obstacles of frame {msg.frame_id} (received {self._age('tracker/obstacles')} s ago)"
        )
        table = Table(title=title, title_justify="left")
        for name in ("id", "state", "motion", "speed m/s", "distance m", "x m", "y m", "age"):
            table.add_column(name, justify="left" if name in ("state", "motion") else "right")
        if msg is None:
            return table
        world_vehicle = invert(np.asarray(msg.ego_pose, dtype=np.float64))
        rows = []
        for ob in msg.obstacles:
            x, y, _ = transform(world_vehicle, np.asarray(ob.centroid, dtype=np.float64)[None])[0]
            rows.append((float(np.hypot(x, y)), ob, x, y))
        for dist, ob, x, y in sorted(rows, key=lambda r: (r[1].state != "tracked", r[0])):
            motion = Text("moving", "red") if ob.moving else Text("stationary", "green")
            table.add_row(str(ob.id), ob.state, motion, f"{ob.speed:.2f}", f"{dist:.1f}", f"{x:.1f}", f"{y:.1f}",
                          str(ob.age))
        return table

    def render(self, vehicle: str) -> Group:
        header = Text(f"stereovox monitor - vehicle {vehicle} - {time.strftime('%H:%M:%S')}", style="bold")
        return Group(header, self.services_table(), self.obstacles_table())


def _status(alive: bool | None) -> Text:
    if alive is None:
        return Text("no token", "yellow")  # reports Health but was never seen alive (joined late?)
    return Text("alive", "green") if alive else Text("gone", "red")


def _pump(health: FifoSubscriber[sv.Health], obstacles: LatestSubscriber[sv.Obstacles], view: VehicleView,
          stop: threading.Event, wakeup: threading.Event) -> None:
    """Hand every delivered message to the view until stopped (runs on its own thread)."""
    while not stop.is_set():
        wakeup.wait(0.2)
        wakeup.clear()
        while (item := health.recv(0.0)) is not None:
            view.on_health(item.msg)
        if (latest := obstacles.recv(0.0)) is not None:
            view.on_obstacles(latest.msg)


def watch(session: zenoh.Session, vehicle: str, view: VehicleView, stop: threading.Event,
          show: Callable[[], object]) -> None:
    """Subscribe read-only, pump messages into ``view`` and call ``show()`` until it returns True."""
    wakeup = threading.Event()
    health: FifoSubscriber[sv.Health] = subscribe(  # type: ignore[assignment]
        session, sv.key_for("health/*", vehicle), sv.Health, policy="fifo", depth=256, wakeup=wakeup
    )
    obstacles: LatestSubscriber[sv.Obstacles] = subscribe(  # type: ignore[assignment]
        session, sv.key_for("tracker/obstacles", vehicle), sv.Obstacles, policy="newest", wakeup=wakeup
    )
    tokens = watch_alive(session, vehicle, view.on_alive)
    pump = threading.Thread(target=_pump, args=(health, obstacles, view, stop, wakeup), daemon=True)
    pump.start()
    try:
        while not stop.is_set():
            if show():
                break
            stop.wait(0.25)
    finally:
        stop.set()
        pump.join(timeout=2)
        tokens.undeclare()
        health.close()
        obstacles.close()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    parser.add_argument("--config", metavar="FILE", help="configuration file (bus credentials, Zenoh TLS file)")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                        help="override a configuration key, e.g. bus.user=monitor (repeatable)")
    parser.add_argument("--vehicle", default=sv.DEFAULT_VEHICLE, help="vehicle name in the keys (default ego)")
    parser.add_argument("--once", action="store_true", help="print one snapshot and exit (scripts, tests)")
    parser.add_argument("--timeout", type=float, default=20.0, help="--once: seconds to wait for a full snapshot")
    parser.add_argument("--foxglove", action="store_true", help="serve a Foxglove WebSocket instead of the dashboard")
    parser.add_argument("--host", default="127.0.0.1", help="--foxglove: address to serve on")
    parser.add_argument("--port", type=int, default=8765, help="--foxglove: port (0 = any free port)")


def run(args: argparse.Namespace) -> int:
    cfg = bus_config(args, args.sets, args.config)
    cfg.bus.vehicle = args.vehicle
    if args.mode is None and cfg.bus.connect:
        cfg.bus.mode = "client"  # a monitor joins a router; it never becomes part of the vehicle's mesh
    stop = stop_on_signals()
    with open_session(cfg.bus) as session:
        if args.foxglove:
            from services.foxglove_live import serve

            return serve(session, args.vehicle, args.host, args.port, stop)
        view = VehicleView()
        if args.once:
            return _once(session, args.vehicle, view, stop, args.timeout)
        from rich.live import Live

        with Live(view.render(args.vehicle), refresh_per_second=4, screen=False) as live:
            watch(session, args.vehicle, view, stop, lambda: live.update(view.render(args.vehicle)))
    return 0


def _once(session: zenoh.Session, vehicle: str, view: VehicleView, stop: threading.Event, timeout_s: float) -> int:
    """Wait for a full snapshot (one with an obstacle if one comes in time), print it, exit."""
    deadline = time.monotonic() + timeout_s
    watch(session, vehicle, view, stop,
          lambda: time.monotonic() > deadline or (not view.missing() and view.has_obstacle()))
    console = Console(width=120) if not sys.stdout.isatty() else Console()
    console.print(view.render(vehicle))
    lacking = view.missing()
    if lacking:
        print(f"monitor: after {timeout_s:.0f} s still missing: {'; '.join(lacking)}", file=sys.stderr)
        return 1
    return 0
