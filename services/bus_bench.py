"""How fast stereo frames cross the bus between two processes: one-way latency and frames per second.

:func:`measure` starts a sender process (``python -m services.bus_bench --send ...``) that
publishes StereoFrames of random pixels, and receives them in this process. Latency is from just
before the sender encodes a frame (its trail's first stamp) to just after the receiver decoded
it, in wall-clock time on one machine — what a stage downstream of the camera actually waits.
A paced run (``rate_hz`` > 0) gives latency without queueing; ``rate_hz=0`` sends flat out and
gives the throughput (with BLOCK congestion control nothing is dropped, so queueing shows up as
latency there instead).

Topologies, to price each network hop of a deployment: direct peer to peer (the default), both
sides clients of a router (``router=ENDPOINT``, or ``--via-router`` to start one on loopback), and
either of them across computers (``--listen-host`` for the receiver's address, ``--sender-prefix``
to start the sender elsewhere, e.g. ``ip netns exec NS``). Latency across computers is only as
good as their common clock (deploy/README.md).
"""

from __future__ import annotations

import argparse
import json
import shlex
import socket
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from common.bus import Publisher, open_session, subscribe
from common.config import BusConfig
from common.errors import BusError
from common.messages import Calibration, StereoFrame, key_for, now_ns

TOPIC = "bench/stereo"


@dataclass
class BenchResult:
    frames_sent: int
    frames_received: int
    rate_hz: float  # asked for; 0 = flat out
    image_format: str
    shared_memory: bool
    payload_bytes: int
    latency_p50_ms: float
    latency_p95_ms: float
    latency_p99_ms: float
    latency_max_ms: float
    frames_per_s: float
    topology: str = "peer"  # peer | router


def random_frame(frame_id: int, width: int, height: int, image_format: str, rng: np.random.Generator) -> StereoFrame:
    left = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    calib = Calibration(fx=700.0, fy=700.0, cx=width / 2, cy=height / 2, baseline=0.54, width=width, height=height)
    return StereoFrame(frame_id=frame_id, stamp_ns=now_ns(), left=left, right=left[:, ::-1].copy(), calib=calib,
                       image_format=image_format)


def send(
    bus: BusConfig, frames: int, rate_hz: float, width: int, height: int, image_format: str, topic: str = TOPIC
) -> None:
    """The sending side: waits until a receiver has subscribed, publishes, stays until it left."""
    rng = np.random.default_rng(0)
    frame = random_frame(0, width, height, image_format, rng)
    with open_session(bus) as session:
        pub = Publisher(session, key_for(topic, bus.vehicle))
        deadline = time.monotonic() + 60
        while not pub.matched():
            if time.monotonic() > deadline:
                raise BusError(f"nobody subscribed to {pub.key} within 60 s")
            time.sleep(0.01)
        period = 1.0 / rate_hz if rate_hz > 0 else 0.0
        next_t = time.monotonic()
        for k in range(frames):
            if period:
                next_t += period
                time.sleep(max(0.0, next_t - time.monotonic()))
            frame.frame_id, frame.stamp_ns = k, now_ns()
            frame.timing = [("camera_replay", frame.stamp_ns, frame.stamp_ns)]
            pub.put(frame)
        deadline = time.monotonic() + 60
        while pub.matched() and time.monotonic() < deadline:  # the receiver leaves once it has all
            time.sleep(0.05)


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def measure(
    frames: int = 300,
    rate_hz: float = 30.0,
    width: int = 640,
    height: int = 480,
    image_format: str = "raw",
    port: int = 0,
    timeout_s: float = 120.0,
    shared_memory: bool = False,
    router: str = "",
    listen_host: str = "127.0.0.1",
    sender_prefix: Sequence[str] = (),
) -> BenchResult:
    """Receive ``frames`` stereo frames from a sender process and time them.

    Peer to peer by default (the receiver listens on ``listen_host``); with ``router`` both sides
    are clients of that router, so every frame crosses two TCP hops instead of one.
    """
    if router:
        bus = BusConfig(mode="client", connect=[router], shared_memory=shared_memory)
        connect, sender_mode = router, ["--client"]
    else:
        connect = f"tcp/{listen_host}:{port or _free_port()}"
        bus = BusConfig(mode="peer", listen=[connect], shared_memory=shared_memory)
        sender_mode = []
    with open_session(bus) as session:
        sub = subscribe(session, key_for(TOPIC), StereoFrame, "fifo", depth=frames + 8)
        cmd = [*sender_prefix, sys.executable, "-m", "services.bus_bench", "--send", "--connect", connect,
               "--frames", str(frames), "--rate", str(rate_hz), "--width", str(width), "--height", str(height),
               "--format", image_format, *sender_mode, *(["--shm"] if shared_memory else [])]
        sender = subprocess.Popen(cmd, start_new_session=True, cwd=Path(__file__).resolve().parent.parent)
        latencies, arrivals, size = [], [], 0
        try:
            deadline = time.monotonic() + timeout_s
            while len(arrivals) < frames and time.monotonic() < deadline and sender.poll() in (None, 0):
                item = sub.recv(0.1)
                if item is None:
                    continue
                latencies.append((item.received_ns - item.msg.timing[0][1]) / 1e6)
                arrivals.append(item.received_ns)
                size = size or item.msg.left.nbytes * 2
        finally:
            sub.close()
            try:
                sender.wait(10)
            except subprocess.TimeoutExpired:
                sender.kill()
    if len(arrivals) < 2:
        raise BusError(f"bus_bench received {len(arrivals)} of {frames} frames (sender exit {sender.returncode})")
    lat = np.array(latencies)
    span_s = (arrivals[-1] - arrivals[0]) / 1e9
    p50, p95, p99 = (round(float(np.percentile(lat, q)), 3) for q in (50, 95, 99))
    return BenchResult(
        frames_sent=frames, frames_received=len(arrivals), rate_hz=rate_hz, image_format=image_format,
        shared_memory=shared_memory, payload_bytes=size, latency_p50_ms=p50, latency_p95_ms=p95,
        latency_p99_ms=p99, latency_max_ms=round(float(lat.max()), 3),
        frames_per_s=round((len(arrivals) - 1) / span_s, 1) if span_s > 0 else 0.0,
        topology="router" if router else "peer",
    )


@contextmanager
def local_router() -> Iterator[str]:
    """A ``stereovox router`` process on a free loopback port, with the deploy JSON5; yields its endpoint."""
    repo = Path(__file__).resolve().parent.parent
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "router", "--listen", endpoint,
         "--config", str(repo / "deploy" / "zenoh" / "router.json5")],
        cwd=repo, stdout=subprocess.DEVNULL, start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                with socket.create_connection(("127.0.0.1", int(endpoint.rsplit(":", 1)[1])), timeout=0.5):
                    break
            except OSError:
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise BusError(f"router on {endpoint} did not start (exit {proc.poll()})") from None
                time.sleep(0.05)
        yield endpoint
    finally:
        stop_router(proc)


def stop_router(proc: subprocess.Popen[str] | subprocess.Popen[bytes]) -> None:
    """SIGTERM, then SIGKILL if the router has not ended within 10 s."""
    proc.terminate()
    try:
        proc.wait(10)
    except subprocess.TimeoutExpired:
        proc.kill()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--send", action="store_true", help="be the sending process (measure() starts it)")
    parser.add_argument("--connect", default="")
    parser.add_argument("--topic", default=TOPIC, help="topic the sender publishes on")
    parser.add_argument("--port", type=int, default=0, help="receiver's loopback port (0 = a free one)")
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--rate", type=float, default=30.0, help="frames per second; 0 = flat out")
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--format", default="raw", choices=("raw", "png", "jpeg"))
    parser.add_argument("--shm", action="store_true", help="Zenoh shared memory on both sides (bus.shared_memory)")
    parser.add_argument("--client", action="store_true", help="sender: be a client of the router at --connect")
    hop = parser.add_mutually_exclusive_group()
    hop.add_argument("--router", default="", metavar="ENDPOINT", help="both sides clients of this router")
    hop.add_argument("--via-router", action="store_true", help="start a router on loopback, both sides its clients")
    parser.add_argument("--listen-host", default="127.0.0.1", help="peer receiver's address (default loopback)")
    parser.add_argument("--sender-prefix", default="", help="command prefix for the sender, e.g. 'ip netns exec A'")
    args = parser.parse_args(argv)
    if args.send:
        mode = "client" if args.client else "peer"
        listen = [] if args.client else ["tcp/127.0.0.1:0"]
        bus = BusConfig(mode=mode, connect=[args.connect], listen=listen, shared_memory=args.shm)
        send(bus, args.frames, args.rate, args.width, args.height, args.format, args.topic)
        return 0
    kwargs = {"shared_memory": args.shm, "listen_host": args.listen_host,
              "sender_prefix": shlex.split(args.sender_prefix)}
    shape = (args.frames, args.rate, args.width, args.height, args.format, args.port)
    if args.via_router:
        with local_router() as endpoint:
            result = measure(*shape, router=endpoint, **kwargs)
    else:
        result = measure(*shape, router=args.router, **kwargs)
    print(json.dumps(asdict(result)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
