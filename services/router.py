"""``stereovox router [--listen ENDPOINT] [--config FILE.json5]``: a Zenoh router as a Python session.

The wheel ships no zenohd, so the router is a session in router mode. Vehicle computers run
their services as clients of one router: a second computer needs only the router's address, and
access control is enforced in one place. Measured here: 1 MB frames at 2.9k msg/s through it.

``--config`` is a Zenoh JSON5 file (deploy/zenoh/router.json5), not the stereovox TOML/YAML tree:
the router has no stage settings, only Zenoh's. Its listen and connect endpoints are used unless
``--listen``/``--connect`` are given (common.bus.zenoh_config writes the bus fields over the
file, so they are read back from it here rather than lost).
"""

from __future__ import annotations

import argparse
import json
import signal
import threading
from pathlib import Path

import zenoh

from common.bus import open_session
from common.config import BusConfig
from common.config_loading import load_config
from common.errors import ConfigError

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"


def file_endpoints(path: str, section: str) -> list[str]:
    """The ``listen`` or ``connect`` endpoints a Zenoh JSON5 file names (mode-dependent maps: the router's)."""
    try:
        conf = zenoh.Config.from_file(path)
    except (zenoh.ZError, OSError) as exc:
        raise ConfigError(f"Zenoh configuration {path}: {exc}") from None
    endpoints = json.loads(conf.get_json(f"{section}/endpoints"))
    if isinstance(endpoints, dict):
        endpoints = endpoints.get("router", [])
    return [str(e) for e in endpoints or []]


def router_bus(listen: list[str], connect: list[str], config: str | None, sets: list[str]) -> BusConfig:
    """The bus section of a router: flags first, then the JSON5 file's endpoints, then the default."""
    bus = load_config(None, sets).bus
    if config:
        if not Path(config).is_file():
            raise ConfigError(f"Zenoh configuration {config} does not exist")
        bus.zenoh_config = config
    bus.mode = "router"
    bus.listen = listen or (file_endpoints(config, "listen") if config else []) or bus.listen or [DEFAULT_LISTEN]
    bus.connect = connect or (file_endpoints(config, "connect") if config else []) or bus.connect
    return bus


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                        help=f"endpoint to listen on (repeatable; default the file's, else {DEFAULT_LISTEN})")
    parser.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                        help="another router to join (repeatable)")
    parser.add_argument("--config", metavar="FILE", help="Zenoh JSON5 configuration (deploy/zenoh/router.json5)")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                        help="a bus.* setting, e.g. bus.user=car (repeatable)")


def run(args: argparse.Namespace) -> int:
    bus = router_bus(args.listen, args.connect, args.config, args.sets)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    with open_session(bus) as session:
        print(f"router ready: zid {session.zid()} listening on {bus.listen}", flush=True)
        stop.wait()
    return 0
