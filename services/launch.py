"""``stereovox launch SPEC.yaml [--host NAME] [--check]``: start and supervise the services a spec puts on a host.

Run it once per computer with that computer's ``--host``; the host that runs the router starts it
first. ``--check`` validates the graph (publishers, schema versions, hosts, endpoints) without
starting anything. The supervision itself (restarts with backoff, logs, clean stop) is
:class:`services.supervisor.Supervisor`; this module is the command around it: a status line
every ``--status-every`` seconds, and SIGINT/SIGTERM stop every child of this host.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from pathlib import Path

from common.errors import ConfigError
from services.launch_spec import LaunchSpec, check, endpoint_address, load_spec
from services.supervisor import Child, Supervisor, client_bus, router_argv, service_argv

__all__ = ["Child", "Supervisor", "client_bus", "endpoint_address", "router_argv", "run", "service_argv"]


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
    parser.add_argument("--check", action="store_true", help="validate the graph and exit (2 if it has problems)")
    parser.add_argument("--var", action="append", default=[], metavar="NAME=VALUE", help="fill a {placeholder}")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                        help="a configuration setting for every service of this host (repeatable)")
    parser.add_argument("--log-dir", type=Path, default=Path("runs/launch-logs"), help="one log file per service")
    parser.add_argument("--status-every", type=float, default=10.0, help="seconds between status lines")
    parser.add_argument("--wait-alive", type=float, default=60.0,
                        help="seconds to wait for the router and the other services before giving up")


def _check(args: argparse.Namespace) -> tuple[LaunchSpec, list[str]]:
    spec = load_spec(args.spec, parse_vars(args.var), strict=not args.check)
    errors = check(spec)
    if args.host is not None and args.host not in spec.hosts:
        errors.append(f"--host {args.host!r} is not among hosts {sorted(spec.hosts)}")
    return spec, errors


def run(args: argparse.Namespace) -> int:
    spec, errors = _check(args)
    if args.check:
        for e in errors:
            print(f"{args.spec}: {e}", file=sys.stderr)
        if spec.unfilled:
            print(f"{args.spec}: not checked, no value given: {sorted(spec.unfilled)}")
        print(f"{args.spec}: {'OK' if not errors else f'{len(errors)} problem(s)'}")
        return 0 if not errors else 2
    if errors:
        raise ConfigError("; ".join(errors))
    extra = [arg for item in args.sets for arg in ("--set", item)]
    sup = Supervisor(spec, args.host, args.log_dir, extra_args=extra)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    name = f"launch {spec.name} host={args.host or 'all'}"
    try:
        sup.start(args.wait_alive, stop)
        print(f"{name}: {sup.status()}", flush=True)
        last = time.monotonic()
        while not stop.wait(0.1):
            sup.poll()
            if all(c.done for c in sup.children.values()):
                break
            if time.monotonic() - last >= args.status_every:
                last = time.monotonic()
                print(f"{name}: {sup.status()}", flush=True)
    finally:
        sup.stop()
        print(f"{name} stopped: {sup.status()}", flush=True)
    return 0
