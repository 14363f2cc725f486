"""``stereovox demo``: every service as its own process over Zenoh on loopback, on the bundled recording.

The graph is deploy/local.yaml (or another with its placeholders, ``--graph``), the same file
``stereovox launch`` runs. The replay runs in
lockstep, so the recording the demo writes matches ``stereovox process`` frame by frame. Any
stage that dies ends the demo with a non-zero exit naming it; every child is stopped in all cases.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import socket
import sys
import threading
import time
from pathlib import Path
from typing import Any

from common.config_loading import recording_overrides
from common.errors import ConfigError, StereovoxError
from common.recording import open_recording
from services.launch import Supervisor
from services.launch_spec import load_spec

log = logging.getLogger("stereovox.demo")

REPO = Path(__file__).resolve().parent.parent
BUNDLED = REPO / "recordings" / "urban.mcap"
LOCAL_SPEC = REPO / "deploy" / "local.yaml"
SOURCE = "camera_replay"


class StageDied(StereovoxError):
    """A service of the demo ended before the replay finished."""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def recording_settings(info: dict[str, Any]) -> list[str]:
    """``--set`` arguments for every service: what the recording says of itself (``recording_overrides``)."""
    return [arg for section, values in recording_overrides(info).items() for key, value in values.items()
            for arg in ("--set", f"{section}.{key}={value}")]


def run_demo(
    recording: Path, out: Path, max_frames: int | None, timeout_s: float | None = None, graph: Path = LOCAL_SPEC
) -> Path:
    """Run the whole graph over ``recording``; returns the path of the run's recording."""
    info = open_recording(recording).info()
    frames = int(info.get("frames") or 10**6)
    frames = min(frames, max_frames) if max_frames else frames
    out.mkdir(parents=True, exist_ok=True)
    run_path = out / "run.mcap"
    run_path.unlink(missing_ok=True)
    variables = {
        "port": str(_free_port()),
        "out": str(out.resolve()),
        "recording": str(recording.resolve()),
        "max_frames": str(frames),
    }
    spec = load_spec(graph, variables)
    fusing = sorted(name for name, svc in spec.services.items() if "vehicle/motion" in svc.inputs)
    if fusing and not open_recording(recording).has_topic("vehicle/motion"):
        raise ConfigError(f"{graph.name}: {', '.join(fusing)} joins every frame with vehicle/motion, "
                          f"but {recording} has none (a KITTI raw or tracking import has)")
    sup = Supervisor(spec, host=None, log_dir=out / "logs", restart=False, extra_args=recording_settings(info))
    deadline = time.monotonic() + (timeout_s or 120.0 + 5.0 * frames)
    stop = threading.Event()
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        sup.start()
        print(f"demo: router at tcp/127.0.0.1:{variables['port']}", file=sys.stderr, flush=True)
        print(f"demo: all services alive, replaying {frames} frames of {recording.name}", file=sys.stderr)
        while not stop.wait(0.1):
            ended = sup.poll()
            source = sup.children[SOURCE]
            if SOURCE in ended:
                code = source.exit_codes[-1]
                if code != 0:
                    raise StageDied(f"camera_replay exited with {code}; log: {source.log_path}")
                break
            dead = [n for n in ended if n != SOURCE]
            if dead:
                child = sup.children[dead[0]]
                raise StageDied(f"stage {dead[0]} died (exit {child.exit_codes[-1]}); log: {child.log_path}")
            if time.monotonic() > deadline:
                raise StageDied(f"demo did not finish in time; logs in {out / 'logs'}")
        else:
            raise KeyboardInterrupt
        code = sup.stop_child("recorder", signal.SIGINT)
        if code not in (0, None):
            raise StageDied(f"recorder exited with {code}; log: {sup.children['recorder'].log_path}")
    finally:
        sup.stop()
        for s, handler in previous.items():
            signal.signal(s, handler)
    return run_path


def summary(report: dict[str, Any], run_path: Path) -> str:
    """A few lines a person reads after the demo: frames, per-stage latency, obstacles."""
    reader = open_recording(run_path)
    moving = stationary = 0
    last: Any = None
    for _, msg in reader.messages(topics=["tracker/obstacles"]):
        last = msg
    if last is not None:
        tracked = [o for o in last.obstacles if o.state == "tracked"]
        moving = sum(o.moving for o in tracked)
        stationary = len(tracked) - moving
    lines = [f"run: {run_path}", f"frames: {report.get('frames')}  throughput: {_fmt(report.get('throughput_hz'))} Hz"]
    for stage, lat in (report.get("latency_ms") or {}).items():
        lines.append(f"  {stage:<14} p50 {_fmt(lat.get('p50'))} ms  p95 {_fmt(lat.get('p95'))} ms")
    lines.append(f"obstacles in the last frame: {moving} moving, {stationary} stationary")
    mv = report.get("moving") or {}
    if mv:
        shares = "  ".join(f"{k} {_fmt(mv.get(k + '_pct'))} %" for k in ("tp", "fp", "fn"))
        lines.append(f"moving obstacles: {shares}")
    return "\n".join(lines)


def _fmt(value: Any) -> str:
    return "n/a" if value is None else f"{value:.1f}" if isinstance(value, float) else str(value)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--recording", type=Path, default=BUNDLED, help="default: the bundled urban recording")
    parser.add_argument("--max-frames", type=int, default=None)
    parser.add_argument("--out", type=Path, default=Path("runs/demo"))
    parser.add_argument("--json", action="store_true", help="print the evaluate JSON as the last line")
    parser.add_argument("--timeout", type=float, default=None, help="seconds before giving up (default: scaled)")
    parser.add_argument("--graph", type=Path, default=LOCAL_SPEC,
                        help="launch spec with local.yaml's placeholders (default deploy/local.yaml; "
                             "deploy/local-ins.yaml fuses a recording's INS into the odometry)")


def run(args: argparse.Namespace) -> int:
    from common.evaluation.evaluate import evaluate_recording

    try:
        run_path = run_demo(args.recording, args.out, args.max_frames, args.timeout, args.graph)
    except StageDied as exc:
        print(f"stereovox demo: {exc}", file=sys.stderr)
        return 1
    report = evaluate_recording(run_path)
    print(summary(report, run_path))
    if args.json:
        print(json.dumps(report))
    return 0
