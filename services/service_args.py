"""Command-line pieces the bus commands share: configuration layers, endpoints, clean stops.

The order of precedence is the configuration tree's (defaults, ``--config`` file, ``--set``),
then the command's own flags, which are the most specific thing the user typed.
"""

from __future__ import annotations

import argparse
import signal
import threading
from typing import Any

from common.config import Config, load_config


def add_bus_arguments(parser: argparse.ArgumentParser) -> None:
    """``--config``, ``--set``, ``--connect``, ``--listen`` and ``--vehicle``."""
    parser.add_argument("--config", help="TOML/YAML configuration file")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override one setting")
    parser.add_argument("--connect", action="append", default=[], metavar="ENDPOINT", help="e.g. tcp/127.0.0.1:7447")
    parser.add_argument("--listen", action="append", default=[], metavar="ENDPOINT", help="e.g. tcp/127.0.0.1:7447")
    parser.add_argument("--vehicle", help="the <vehicle> part of every key (default bus.vehicle)")


def config_from_args(args: argparse.Namespace, flags: dict[str, Any]) -> Config:
    """The effective configuration; ``flags`` maps ``section.field`` to a flag's value (None = not given)."""
    cfg = load_config(args.config, args.set)
    for dotted, value in flags.items():
        if value is not None:
            section, name = dotted.split(".", 1)
            setattr(getattr(cfg, section), name, value)
    if args.connect:
        cfg.bus.connect = list(args.connect)
    if args.listen:
        cfg.bus.listen = list(args.listen)
    if args.vehicle:
        cfg.bus.vehicle = args.vehicle
    return cfg


def stop_on_signals() -> threading.Event:
    """An event set by SIGINT or SIGTERM, so the command finishes its files instead of dying."""
    stop = threading.Event()

    def handler(signum: int, frame: Any) -> None:
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    return stop
