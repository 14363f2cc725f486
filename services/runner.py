"""``stereovox run SERVICE``: one pipeline stage as its own process, on its own Zenoh session.

The configuration is the one typed tree (defaults, then ``--config FILE``, then ``--set``); the
bus flags (``--connect``, ``--listen``, ``--mode``) are shorthands for ``bus.*`` keys. SIGINT and
SIGTERM only set a stop event: the service's loop looks at it between timed waits, closes its
subscribers, publishers and liveliness token, and the process exits 0.

The recorder and the camera replay need more than a configuration (a file to write or read), so
they are their own commands, ``stereovox record`` and ``stereovox replay``; they take the same
bus flags through :func:`add_bus_arguments`, :func:`bus_config` and :func:`stop_on_signals`.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import signal
import threading
from types import FrameType

from common.bus import QUEUE_POLICIES, open_session
from common.config import Config
from common.config_loading import load_config
from services.shell import run_stage

log = logging.getLogger(__name__)

#: stage name -> module exposing ``stage(cfg) -> Stage`` (the core wired to its keys).
SERVICES: dict[str, str] = {
    "stereo_depth": "services.stereo_depth.service",
    "odometry": "services.odometry.service",
    "voxel_mapper": "services.voxel_mapper.service",
    "tracker": "services.tracker.service",
}


def add_bus_arguments(parser: argparse.ArgumentParser) -> None:
    """``--connect/--listen/--mode``: how this process joins the bus (also used by ``topics``)."""
    parser.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                        help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)")
    parser.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                        help="endpoint to listen on (repeatable; default an ephemeral loopback port)")
    parser.add_argument("--mode", choices=("peer", "client"), default=None, help="Zenoh mode (default peer)")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("service", choices=list(SERVICES),
                        help="which stage to run (the recorder and replay: stereovox record / replay)")
    parser.add_argument("--config", metavar="FILE", help="TOML/YAML configuration file")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                        help="override one configuration key, e.g. voxel.edge=0.2 (repeatable)")
    add_bus_arguments(parser)
    parser.add_argument("--policy", choices=QUEUE_POLICIES, default="newest",
                        help="input queue: newest (live, drops and counts) or fifo (lockstep, no drops)")
    parser.add_argument("--max-frames", type=int, default=0, metavar="N", help="exit after N frames out (0 = never)")


def bus_config(args: argparse.Namespace, sets: list[str] | None = None, file: str | None = None) -> Config:
    """The configuration tree with the bus flags applied on top of file and ``--set``."""
    cfg = load_config(file, sets or [])
    if args.connect:
        cfg.bus.connect = list(args.connect)
    if args.listen:
        cfg.bus.listen = list(args.listen)
    if args.mode:
        cfg.bus.mode = args.mode
    return cfg


def stop_on_signals() -> threading.Event:
    """An event set by SIGINT or SIGTERM, instead of KeyboardInterrupt at an arbitrary point."""
    stop = threading.Event()

    def handler(signum: int, _frame: FrameType | None) -> None:
        log.info("signal %s: stopping", signal.Signals(signum).name)
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    return stop


def run(args: argparse.Namespace) -> int:
    cfg = bus_config(args, args.sets, args.config)
    module = importlib.import_module(SERVICES[args.service])
    stop = stop_on_signals()
    with open_session(cfg.bus) as session:
        listen = cfg.bus.listen or ("-" if cfg.bus.mode == "client" else "an ephemeral loopback port")
        log.info("%s: joined the bus as %s (listen %s, connect %s)", args.service, cfg.bus.mode, listen,
                 cfg.bus.connect or "-")
        run_stage(module.stage(cfg), cfg, session, stop, args.policy, max_frames=args.max_frames)
    return 0
