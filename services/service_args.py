"""Command-line pieces the bus commands share: configuration layers, endpoints, clean stops.

The order of precedence is the configuration tree's (defaults, ``--config`` file, ``--set``),
then the command's own flags, which are the most specific thing the user typed.
"""

from __future__ import annotations

import argparse
from typing import Any

from common.config import Config
from services import runner


def add_bus_arguments(parser: argparse.ArgumentParser) -> None:
    """``--config``, ``--set``, ``--vehicle`` and the runner's ``--connect/--listen/--mode``.

    The same flags as ``stereovox run``, so a launch spec starts ``record`` and ``replay`` with
    the command line it gives every service.
    """
    parser.add_argument("--config", help="TOML/YAML configuration file")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override one setting")
    parser.add_argument("--vehicle", help="the <vehicle> part of every key (default bus.vehicle)")
    runner.add_bus_arguments(parser)


def config_from_args(args: argparse.Namespace, flags: dict[str, Any]) -> Config:
    """The effective configuration; ``flags`` maps ``section.field`` to a flag's value (None = not given)."""
    cfg = runner.bus_config(args, args.set, args.config)
    for dotted, value in flags.items():
        if value is not None:
            section, name = dotted.split(".", 1)
            setattr(getattr(cfg, section), name, value)
    if args.vehicle:
        cfg.bus.vehicle = args.vehicle
    return cfg


stop_on_signals = runner.stop_on_signals
