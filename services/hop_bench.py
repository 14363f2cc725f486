"""What each network hop adds: one frame stream timed direct, through a router, and between two hosts.

``python -m services.hop_bench`` runs :mod:`services.bus_bench` (a sender process, a receiver
that times every frame from just before encoding to just after decoding) in four topologies of
a deployment, each several times, and prints median p50 and p95 latencies per topology and
payload with what it adds over the direct loopback pair:

- ``peer``: sender and receiver peer to peer on 127.0.0.1 — one TCP hop on loopback;
- ``router``: both clients of a ``stereovox router`` on 127.0.0.1 — two hops and the routing;
- ``netns-peer``: sender in namespace A, receiver in B, peer to peer across a veth pair;
- ``netns-router``: router and sender in A, receiver in B: what a service on ``perception-b``
  waits for a key published on ``perception-a`` in deploy/two-computers.yaml.

Each run is a fresh pair of processes and the topologies take turns, run after run, so a busy
spell on a shared machine hits every row alike; medians over the runs are reported. Namespaces
need root; without it the two ``netns`` rows are left out and it says why. Both hosts share
one clock here, so cross-host latency is exact; on a vehicle it is only as good as the clock
synchronisation (deploy/README.md, "Time").
"""

from __future__ import annotations

import argparse
import itertools
import json
import shlex
import subprocess
import sys
import time
from collections import defaultdict
from collections.abc import Iterator, Sequence
from contextlib import AbstractContextManager, ExitStack, contextmanager
from pathlib import Path

import numpy as np

from common.errors import BusError
from services.bus_bench import BenchResult, local_router, stop_router
from services.netns import TwoHosts, two_namespaces

REPO = Path(__file__).resolve().parent.parent
PAYLOADS = {"stereo": (640, 480), "small": (16, 12)}  # raw RGB pairs: 1.8 MB and ~1 KB
PORT = 17447  # inside the namespaces nothing else listens, so a fixed port is safe there


def bench(args: Sequence[str], prefix: Sequence[str] = (), timeout_s: float = 180.0) -> BenchResult:
    """One bus_bench run (receiver started with ``prefix``, e.g. in a namespace); its JSON result."""
    cmd = [*prefix, sys.executable, "-m", "services.bus_bench", *args]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=timeout_s)
    if proc.returncode != 0:
        raise BusError(f"{shlex.join(cmd)} failed: {proc.stderr.strip()[-500:]}")
    return BenchResult(**json.loads(proc.stdout.strip().splitlines()[-1]))


@contextmanager
def router_in(hosts: TwoHosts) -> Iterator[str]:
    """A router in namespace A on its veth address; yields its endpoint once it says it is ready."""
    endpoint = f"tcp/{hosts.addr_a}:{PORT}"
    cmd = [*hosts.prefix_a, sys.executable, "-m", "services.cli", "router", "--listen", endpoint,
           "--config", str(REPO / "deploy" / "zenoh" / "router.json5")]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, text=True, start_new_session=True)
    try:
        line = proc.stdout.readline() if proc.stdout else ""
        if "router ready" not in line:
            raise BusError(f"router in namespace did not start: {line!r} (exit {proc.poll()})")
        yield endpoint
    finally:
        stop_router(proc)


def topologies(hosts: TwoHosts | None) -> Iterator[tuple[str, list[str], list[str], AbstractContextManager[str]]]:
    """(name, receiver prefix, bus_bench arguments, router context yielding its endpoint or "")."""
    yield "peer", [], [], _no_router()
    yield "router", [], [], local_router()
    if hosts is None:
        return
    sender = ["--sender-prefix", shlex.join(hosts.prefix_a)]
    yield "netns-peer", hosts.prefix_b, ["--listen-host", hosts.addr_b, *sender], _no_router()
    yield "netns-router", hosts.prefix_b, sender, router_in(hosts)


def run_all(frames: int, rate: float, runs: int, payloads: Sequence[str]) -> list[dict[str, object]]:
    """Every topology x payload, ``runs`` times each, interleaved (a busy spell hits every row alike)."""
    results: dict[tuple[str, str], list[BenchResult]] = defaultdict(list)
    with two_namespaces("svh") as (hosts, why_not), ExitStack() as stack:
        if hosts is None:
            print(f"network namespaces unavailable ({why_not}): netns rows left out", file=sys.stderr)
        rows = [(name, prefix, [*extra, *(["--router", endpoint] if endpoint else [])])
                for name, prefix, extra, router in topologies(hosts)
                for endpoint in [stack.enter_context(router)]]
        for run in range(runs):
            for (name, prefix, extra), payload in itertools.product(rows, payloads):
                width, height = PAYLOADS[payload]
                args = ["--frames", str(frames), "--rate", str(rate), "--width", str(width),
                        "--height", str(height), *extra]
                results[name, payload].append(bench(args, prefix))
            print(f"run {run + 1}/{runs} done", file=sys.stderr, flush=True)
    return [_row(name, payload, r) for (name, payload), r in results.items()]


@contextmanager
def _no_router() -> Iterator[str]:
    yield ""


def _row(topology: str, payload: str, results: list[BenchResult]) -> dict[str, object]:
    return {
        "topology": topology, "payload": payload, "bytes": results[0].payload_bytes, "runs": len(results),
        "received": f"{sum(r.frames_received for r in results)}/{sum(r.frames_sent for r in results)}",
        "p50_ms": round(float(np.median([r.latency_p50_ms for r in results])), 3),
        "p95_ms": round(float(np.median([r.latency_p95_ms for r in results])), 3),
    }


def table(rows: list[dict[str, object]]) -> str:
    """Markdown: each row with what it adds over the direct loopback pair of the same payload."""
    base = {r["payload"]: r for r in rows if r["topology"] == "peer"}
    lines = ["| topology | payload | p50 ms | p95 ms | adds p50 / p95 over peer loopback |",
             "| --- | --- | --- | --- | --- |"]
    for r in rows:
        b = base[r["payload"]]
        added = f"{float(r['p50_ms']) - float(b['p50_ms']):+.2f} / {float(r['p95_ms']) - float(b['p95_ms']):+.2f}"
        lines.append(f"| {r['topology']} | {r['payload']} ({r['bytes']} B) | {r['p50_ms']} | {r['p95_ms']} | "
                     f"{'—' if r is b else added} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=150, help="frames per run")
    parser.add_argument("--rate", type=float, default=30.0, help="frames per second (paced: no queueing)")
    parser.add_argument("--runs", type=int, default=3, help="runs per topology and payload (medians)")
    parser.add_argument("--payload", action="append", choices=sorted(PAYLOADS), help="default: all")
    args = parser.parse_args(argv)
    started = time.monotonic()
    rows = run_all(args.frames, args.rate, args.runs, args.payload or list(PAYLOADS))
    print(table(rows))
    print(f"\n{args.runs} runs x {args.frames} frames at {args.rate:g} Hz per row, medians of the per-run "
          f"percentiles; {time.monotonic() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
