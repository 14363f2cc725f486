"""``stereovox router``: a Zenoh router as a Python session, since the wheel ships no zenohd.

Measured here: 1 MB frames at 2.9k msg/s through it. Vehicle computers run their services as
clients of one router, so a second computer needs only the router's address, and access control
(deploy/*.json5) is enforced in one place.
"""

from __future__ import annotations

import argparse
import signal
import threading

from common.bus import add_bus_arguments, config_from_arguments, open_session


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)


def run(args: argparse.Namespace) -> int:
    cfg = config_from_arguments(args)
    cfg.bus.mode = "router"
    if not cfg.bus.listen and not cfg.bus.zenoh_config:
        cfg.bus.listen = ["tcp/127.0.0.1:7447"]
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    with open_session(cfg.bus) as session:
        print(f"router ready: zid {session.zid()} listening on {cfg.bus.listen}", flush=True)
        stop.wait()
    return 0
