"""``stereovox launch SPEC.yaml [--host NAME]``: start and supervise the services a spec puts on this host.

Each service is a child process in its own process group with its log in a file; a crashed
service is restarted with exponential backoff (its restart policy permitting); SIGINT/SIGTERM
stop every child, SIGKILL for those that do not end in time. Sources (the camera) start only
once every other local service announces itself alive, so no first frame is lost.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

from common.bus import open_session, watch_alive
from common.config import BusConfig
from common.errors import ConfigError
from services.launch_spec import LaunchSpec, ServiceSpec, check, load_spec

log = logging.getLogger("stereovox.launch")

ROUTER = "router"
BACKOFF_START_S = 0.25
BACKOFF_MAX_S = 8.0
STABLE_AFTER_S = 20.0  # a service up this long gets its backoff reset


@dataclass
class Child:
    """One supervised service and its restart bookkeeping."""

    name: str
    argv: list[str]
    restart: str
    log_path: Path
    proc: subprocess.Popen[bytes] | None = None
    started_at: float = 0.0
    restarts: int = 0
    backoff_s: float = BACKOFF_START_S
    next_start: float | None = None
    exit_codes: list[int] = field(default_factory=list)
    done: bool = False  # ended and will not be restarted

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None


def service_argv(spec: LaunchSpec, svc: ServiceSpec, extra: list[str] | None = None) -> list[str]:
    """The command line of a service: its stereovox sub-command, as a client of the spec's router."""
    argv = [sys.executable, "-m", "services.cli", *svc.command, "--mode", "client"]
    argv += ["--connect", spec.router_endpoint(), "--set", f"bus.vehicle={spec.vehicle}"]
    return argv + list(extra or [])


def endpoint_address(endpoint: str) -> tuple[str, int]:
    """``tcp/127.0.0.1:7447`` -> ("127.0.0.1", 7447)."""
    match = re.fullmatch(r"(?:tcp|tls)/\[?([^\]]+?)\]?:(\d+)", endpoint)
    if not match:
        raise ConfigError(f"router endpoint {endpoint!r} is not tcp/HOST:PORT or tls/HOST:PORT")
    return match.group(1), int(match.group(2))


def router_argv(spec: LaunchSpec) -> list[str]:
    return [sys.executable, "-m", "services.cli", "router", "--listen", spec.router_listen]


class Supervisor:
    """Starts, watches, restarts and stops the children of one host."""

    def __init__(
        self,
        spec: LaunchSpec,
        host: str | None,
        log_dir: Path,
        restart: bool = True,
        env: dict[str, str] | None = None,
        extra_args: list[str] | None = None,
    ) -> None:
        """``extra_args`` go to every service (e.g. ``--set volume.x_max=45`` for a KITTI run)."""
        self.spec = spec
        self.host = host
        self.log_dir = log_dir
        self.allow_restart = restart
        self.env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        log_dir.mkdir(parents=True, exist_ok=True)
        self.children: dict[str, Child] = {}
        if host is None or spec.router_host == host:
            self.children[ROUTER] = Child(ROUTER, router_argv(spec), "always", log_dir / "router.log")
        for svc in spec.on_host(host):
            argv = service_argv(spec, svc, extra_args)
            self.children[svc.name] = Child(svc.name, argv, svc.restart, log_dir / f"{svc.name}.log")
        self.sources = {s.name for s in spec.on_host(host) if s.source}
        self.alive: set[str] = set()
        self._alive_lock = threading.Lock()

    def _spawn(self, child: Child) -> None:
        with open(child.log_path, "ab") as logf:
            child.proc = subprocess.Popen(
                child.argv, stdout=logf, stderr=subprocess.STDOUT, env=self.env, start_new_session=True
            )
        child.started_at = time.monotonic()
        child.next_start = None
        log.info("%-14s started pid %d (restarts %d)", child.name, child.proc.pid, child.restarts)

    def _on_alive(self, service: str, alive: bool) -> None:
        with self._alive_lock:
            (self.alive.add if alive else self.alive.discard)(service)

    def start(self, wait_alive_s: float = 60.0) -> None:
        """Router first, then every service but the sources; the sources once the others are alive."""
        if ROUTER in self.children:
            self._spawn(self.children[ROUTER])
            self._wait_router(wait_alive_s)
        others = [c for n, c in self.children.items() if n != ROUTER and n not in self.sources]
        for child in others:
            self._spawn(child)
        if not self.sources:
            return
        expected = {c.name for c in others}
        bus = BusConfig(mode="client", connect=[self.spec.router_endpoint()], vehicle=self.spec.vehicle)
        self._session = _open_with_retry(bus, wait_alive_s)
        self._watch = watch_alive(self._session, self.spec.vehicle, self._on_alive)
        deadline = time.monotonic() + wait_alive_s
        while time.monotonic() < deadline:
            self.poll()
            with self._alive_lock:
                if expected <= self.alive:
                    break
            dead = [c.name for c in others if c.done]
            if dead:
                raise ConfigError(f"service(s) {dead} exited before becoming alive; see {self.log_dir}")
            time.sleep(0.05)
        else:
            with self._alive_lock:
                missing = sorted(expected - self.alive)
            raise ConfigError(f"services not alive after {wait_alive_s:.0f} s: {missing}; see {self.log_dir}")
        for name in self.sources:
            self._spawn(self.children[name])

    def _wait_router(self, timeout_s: float) -> None:
        """Clients that start before the router listens fail their first connect: wait for its port."""
        host, port = endpoint_address(self.spec.router_endpoint())
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            router = self.children[ROUTER]
            if router.proc is not None and router.proc.poll() is not None:
                raise ConfigError(f"router exited with {router.proc.returncode}; see {router.log_path}")
            try:
                with socket.create_connection((host, port), timeout=0.5):
                    return
            except OSError:
                time.sleep(0.05)
        raise ConfigError(f"router not listening on {host}:{port} after {timeout_s:.0f} s")

    def poll(self) -> list[str]:
        """Restart what crashed (policy and backoff permitting); returns names that ended for good."""
        now = time.monotonic()
        ended: list[str] = []
        for child in self.children.values():
            if child.done:
                continue
            if child.proc is None:
                if child.next_start is not None and now >= child.next_start:
                    self._spawn(child)
                continue
            code = child.proc.poll()
            if code is None:
                if now - child.started_at > STABLE_AFTER_S:
                    child.backoff_s = BACKOFF_START_S
                continue
            child.exit_codes.append(code)
            child.proc = None
            wants = child.restart == "always" or (child.restart == "on-failure" and code != 0)
            if self.allow_restart and wants:
                child.restarts += 1
                child.next_start = now + child.backoff_s
                log.warning("%-14s exited with %d; restart in %.2f s", child.name, code, child.backoff_s)
                child.backoff_s = min(child.backoff_s * 2, BACKOFF_MAX_S)
            else:
                child.done = True
                ended.append(child.name)
                log.info("%-14s exited with %d", child.name, code)
        return ended

    def stop_child(self, name: str, sig: int = signal.SIGINT, timeout_s: float = 15.0) -> int | None:
        """Stop one child and its group; SIGKILL if it does not end within ``timeout_s``."""
        child = self.children[name]
        child.done = True
        proc = child.proc
        if proc is None:
            return child.exit_codes[-1] if child.exit_codes else None
        if proc.poll() is None:
            _signal_group(proc, sig)
            try:
                proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                log.warning("%-14s did not stop in %.0f s: killed", name, timeout_s)
                _signal_group(proc, signal.SIGKILL)
                proc.wait(5)
        child.exit_codes.append(int(proc.returncode))
        return int(proc.returncode)

    def stop(self, timeout_s: float = 15.0) -> None:
        """Stop everything: services first (sources first of all), the router last."""
        order = sorted(self.children, key=lambda n: (n == ROUTER, n not in self.sources))
        for name in order:
            if self.children[name].proc is not None:
                _signal_group(self.children[name].proc, signal.SIGINT)  # type: ignore[arg-type]
        for name in order:
            self.stop_child(name, timeout_s=timeout_s)
        session = getattr(self, "_session", None)
        if session is not None:
            session.close()

    def status(self) -> str:
        parts = []
        for c in self.children.values():
            state = "up" if c.running else ("done" if c.done else "restarting")
            parts.append(f"{c.name}={state}" + (f"(r{c.restarts})" if c.restarts else ""))
        return " ".join(parts)


def _signal_group(proc: subprocess.Popen[bytes], sig: int) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, sig)


def _open_with_retry(bus: BusConfig, timeout_s: float) -> zenoh.Session:
    """The router may still be starting: retry the client session until it answers."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return open_session(bus)
        except Exception:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)


def parse_vars(items: list[str]) -> dict[str, str]:
    out = {}
    for item in items:
        if "=" not in item:
            raise ConfigError(f"--var takes NAME=VALUE, got {item!r}")
        k, v = item.split("=", 1)
        out[k.strip()] = v
    return out


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("spec", type=Path, help="launch spec (deploy/*.yaml)")
    parser.add_argument("--host", default=None, help="start only this host's services (default: all)")
    parser.add_argument("--check", action="store_true", help="validate the graph and exit")
    parser.add_argument("--var", action="append", default=[], metavar="NAME=VALUE", help="fill a {placeholder}")
    parser.add_argument("--log-dir", type=Path, default=Path("runs/launch-logs"))
    parser.add_argument("--status-every", type=float, default=10.0, help="seconds between status lines")


def run(args: argparse.Namespace) -> int:
    spec = load_spec(args.spec, parse_vars(args.var), strict=not args.check)
    errors = check(spec)
    if args.host is not None and args.host not in spec.hosts:
        errors.append(f"--host {args.host!r} is not among hosts {sorted(spec.hosts)}")
    if args.check:
        for e in errors:
            print(f"{spec.path}: {e}", file=sys.stderr)
        print(f"{spec.path}: {'OK' if not errors else f'{len(errors)} problem(s)'}")
        return 0 if not errors else 2
    if errors:
        raise ConfigError("; ".join(errors))
    sup = Supervisor(spec, args.host, args.log_dir)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        sup.start()
        print(f"launch {spec.name} host={args.host or 'all'}: {sup.status()}", flush=True)
        last = time.monotonic()
        while not stop.wait(0.1):
            sup.poll()
            if all(c.done for c in sup.children.values()):
                break
            if time.monotonic() - last >= args.status_every:
                last = time.monotonic()
                print(f"launch {spec.name}: {sup.status()}", flush=True)
    finally:
        sup.stop()
    return 0
