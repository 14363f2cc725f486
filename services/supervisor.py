"""The supervisor behind ``stereovox launch``, ``demo`` and ``bench``: one host's services as child processes.

Each service is a child in its own process group with its log in a file. A crashed service is
restarted with exponential backoff (its restart policy permitting), reset once it has stayed up.
The router (when this host runs it) starts first and the others wait for its port; sources
start last, once every non-source service of the whole spec (every host) has its liveliness
token up, so a camera on one computer never sends into a graph whose other half is still booting.
A liveliness watcher also times each restart: from the crash to the new token. Each child
finds in ``STEREOVOX_RESTARTS`` how often it was restarted before, so a restarted recorder
continues in a new file instead of truncating the one its predecessor wrote.
"""

from __future__ import annotations

import contextlib
import logging
import os
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
from common.lifeline import SUPERVISOR_ENV
from services.launch_spec import LaunchSpec, ServiceSpec, endpoint_address

log = logging.getLogger("stereovox.launch")

ROUTER = "router"
BACKOFF_START_S = 0.1  # the first restart almost at once; a crash loop backs off to 8 s
BACKOFF_MAX_S = 8.0
STABLE_AFTER_S = 20.0  # a service up this long gets its backoff reset
RESTARTS_ENV = "STEREOVOX_RESTARTS"  # how often this child was restarted before, for the child itself


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
    died_at: float | None = None  # when the last crash was seen, until the service is alive again
    recovery_s: list[float] = field(default_factory=list)  # crash -> liveliness token back, per restart

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None


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
        self._session: zenoh.Session | None = None
        self._watch: zenoh.Subscriber | None = None

    def _spawn(self, child: Child) -> None:
        env = {**self.env, RESTARTS_ENV: str(child.restarts),  # a restarted recorder must not overwrite its file
               SUPERVISOR_ENV: str(os.getpid())}  # and every child ends with this process (common/lifeline.py)
        with open(child.log_path, "ab") as logf:
            child.proc = subprocess.Popen(
                child.argv, stdout=logf, stderr=subprocess.STDOUT, env=env, start_new_session=True
            )
        child.started_at = time.monotonic()
        child.next_start = None
        log.info("%-14s started pid %d (restarts %d)", child.name, child.proc.pid, child.restarts)

    def _on_alive(self, service: str, alive: bool) -> None:
        with self._alive_lock:
            (self.alive.add if alive else self.alive.discard)(service)
        child = self.children.get(service)
        if alive and child is not None and child.died_at is not None:
            child.recovery_s.append(time.monotonic() - child.died_at)
            child.died_at = None
            log.info("%-14s alive again %.2f s after it died", service, child.recovery_s[-1])

    def start(self, wait_alive_s: float = 60.0, stop: threading.Event | None = None) -> None:
        """Router first, then every service but the sources; the sources once the graph is alive."""
        stop = stop or threading.Event()
        if ROUTER in self.children:
            self._spawn(self.children[ROUTER])
        self._wait_router(wait_alive_s, stop)
        others = [c for n, c in self.children.items() if n != ROUTER and n not in self.sources]
        for child in others:
            self._spawn(child)
        self._session = _open_with_retry(client_bus(self.spec), wait_alive_s)
        self._watch = watch_alive(self._session, self.spec.vehicle, self._on_alive)
        if not self.sources:
            return
        expected = {s.name for s in self.spec.services.values() if not s.source}
        deadline = time.monotonic() + wait_alive_s
        while not stop.is_set():
            self.poll()
            with self._alive_lock:
                missing = sorted(expected - self.alive)
            if not missing:
                break
            dead = [c.name for c in others if c.done]
            if dead:
                raise ConfigError(f"service(s) {dead} exited before becoming alive; see {self.log_dir}")
            if time.monotonic() > deadline:
                raise ConfigError(f"services not alive after {wait_alive_s:.0f} s: {missing}; see {self.log_dir}")
            time.sleep(0.05)
        if not stop.is_set():
            for name in self.sources:
                self._spawn(self.children[name])

    def _wait_router(self, timeout_s: float, stop: threading.Event) -> None:
        """Clients that start before the router listens fail their first connect: wait for its port."""
        host, port = endpoint_address(self.spec.router_endpoint())
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not stop.is_set():
            router = self.children.get(ROUTER)
            if router is not None and router.proc is not None and router.proc.poll() is not None:
                raise ConfigError(f"router exited with {router.proc.returncode}; see {router.log_path}")
            try:
                with socket.create_connection((host, port), timeout=0.5):
                    return
            except OSError:
                time.sleep(0.05)
        if not stop.is_set():
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
                child.died_at = now
                child.next_start = now + child.backoff_s
                log.warning("%-14s exited with %d; restart in %.2f s", child.name, code, child.backoff_s)
                child.backoff_s = min(child.backoff_s * 2, BACKOFF_MAX_S)
            else:
                child.done = True
                ended.append(child.name)
                log.info("%-14s exited with %d", child.name, code)
        return ended

    def stop_child(self, name: str, sig: int | None = signal.SIGINT, timeout_s: float = 15.0) -> int | None:
        """Stop one child and its group; SIGKILL if it does not end within ``timeout_s``.

        ``sig=None`` only waits: a second SIGINT would land while Python shuts down, with the
        default handler back in place, and turn a clean exit into death by signal.
        """
        child = self.children[name]
        child.done = True
        proc = child.proc
        if proc is None:
            return child.exit_codes[-1] if child.exit_codes else None
        if proc.poll() is None:
            if sig is not None:
                _signal_group(proc, sig)
            try:
                proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                log.warning("%-14s did not stop in %.0f s: killed", name, timeout_s)
                _signal_group(proc, signal.SIGKILL)
                proc.wait(5)
        child.exit_codes.append(int(proc.returncode))
        child.proc = None
        return int(proc.returncode)

    def stop(self, timeout_s: float = 15.0) -> None:
        """Stop everything: sources first (nothing new enters), then the stages, then sinks, the router last."""
        if self._watch is not None:
            with contextlib.suppress(Exception):
                self._watch.undeclare()
            self._watch = None
        if self._session is not None:
            with contextlib.suppress(Exception):
                self._session.close()
            self._session = None
        sinks = {s.name for s in self.spec.on_host(self.host) if not s.outputs and not s.source}
        order = sorted(self.children, key=lambda n: (n == ROUTER, n in sinks, n not in self.sources))
        first = [n for n in order if n != ROUTER and n not in sinks]
        for name in first:
            proc = self.children[name].proc
            if proc is not None:
                _signal_group(proc, signal.SIGINT)
        for name in order:  # sinks (the recorder) only once the others ended: their last outputs are kept
            self.stop_child(name, sig=None if name in first else signal.SIGINT, timeout_s=timeout_s)

    def status(self) -> str:
        """One line: every child's state, pid, restarts and last exit code."""
        parts = []
        for c in self.children.values():
            state = "up" if c.running else ("done" if c.done else "restarting")
            details = [f"pid {c.proc.pid}"] if c.running and c.proc is not None else []
            details += [f"r{c.restarts}"] if c.restarts else []
            details += [f"exit {c.exit_codes[-1]}"] if c.exit_codes else []
            parts.append(f"{c.name}={state}" + (f"({', '.join(details)})" if details else ""))
        return " ".join(parts)


def service_argv(spec: LaunchSpec, svc: ServiceSpec, extra: list[str] | None = None) -> list[str]:
    """The command line of a service: its stereovox sub-command, as a client of the spec's router.

    A ``run`` stage without ``--policy`` gets its inputs' queue policy from the spec, so the queue
    a key is read with is written once, next to the key.
    """
    argv = [sys.executable, "-m", "services.cli", *svc.command, "--mode", "client"]
    policy = svc.queue_policy()
    if svc.command[0] == "run" and "--policy" not in svc.command and policy is not None:
        argv += ["--policy", policy]
    argv += ["--connect", spec.router_endpoint(), "--set", f"bus.vehicle={spec.vehicle}"]
    if "client" in spec.zenoh:
        argv += ["--set", f"bus.zenoh_config={spec.zenoh['client']}"]
    return argv + list(extra or [])


def router_argv(spec: LaunchSpec) -> list[str]:
    argv = [sys.executable, "-m", "services.cli", "router", "--listen", spec.router_listen]
    return argv + (["--config", str(spec.zenoh["router"])] if "router" in spec.zenoh else [])


def client_bus(spec: LaunchSpec) -> BusConfig:
    """How the launcher itself watches liveliness: a client of the router, like its services."""
    conf = str(spec.zenoh.get("client", ""))
    return BusConfig(mode="client", connect=[spec.router_endpoint()], vehicle=spec.vehicle, zenoh_config=conf)


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
