"""The ``stereovox`` command: one sub-command per module, imported only when used.

Each module named in COMMANDS exposes ``add_arguments(parser)`` and ``run(args) -> int``; the
argument parsing lives there, next to the code it drives, and this file only dispatches.
Errors stereovox raises on purpose print one line and exit 2; nothing else is caught.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from common.errors import StereovoxError
from common.lifeline import follow_supervisor

#: sub-command -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "run": ("services.runner", "run one service as its own process"),
    "record": ("services.recorder", "record bus keys to MCAP"),
    "replay": ("services.camera_replay", "publish a recording's frames and ground truth"),
    "topics": ("services.topics", "list, echo or measure the rate of bus keys"),
    "simulate": ("common.scenarios.simulate", "render a synthetic stereo driving scenario with ground truth"),
    "evaluate": ("common.evaluation.evaluate", "score a run against its ground truth"),
    "import": ("common.datasets.importer", "import KITTI, Middlebury or a ROS 2 bag into a recording"),
    "process": ("services.pipeline", "run every stage in one process over a recording (no bus)"),
    "demo": ("services.demo", "run the whole pipeline as separate processes on the bundled recording"),
    "launch": ("services.launch", "start and supervise the services a launch spec puts on this host"),
    "bench": ("services.bench", "measure per-stage, in-process and distributed speed, memory and CPU"),
    "router": ("services.router", "run a Zenoh router (the wheel ships no zenohd)"),
    "monitor": ("services.monitor", "watch a running vehicle: terminal dashboard or Foxglove live view (read-only)"),
    "export": ("services.export", "convert a recording to Foxglove's own schemas (opens in the Foxglove app)"),
    "render": ("services.render", "draw obstacle boxes on the left image beside a bird's-eye view (PNG, MP4)"),
}


def _top_parser() -> tuple[argparse.ArgumentParser, argparse._SubParsersAction]:
    parser = argparse.ArgumentParser(prog="stereovox", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    return parser, sub


def build_parser(argv: Sequence[str]) -> argparse.ArgumentParser:
    """Import only the module the command needs, so `stereovox replay` does not load OpenCV's SGBM."""
    parser, sub = _top_parser()
    name = next((a for a in argv if not a.startswith("-")), None)
    for command, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(command, help=help_text, description=help_text)
        p.set_defaults(_module=module)
        if command == name:
            importlib.import_module(module).add_arguments(p)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    follow_supervisor()
    args_list = list(sys.argv[1:] if argv is None else argv)
    args = build_parser(args_list).parse_args(args_list)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
    )
    try:
        return int(importlib.import_module(args._module).run(args) or 0)
    except StereovoxError as exc:
        print(f"stereovox {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
