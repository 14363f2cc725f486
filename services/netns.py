"""Two "computers" on one machine: network namespaces joined by a veth pair, for tests and benches.

A deployment across computers is only tested for real when its traffic crosses a real network
interface with addresses that are not loopback. Two namespaces joined by a veth pair give exactly
that without hardware: the kernel routes between them as between two hosts on one Ethernet
segment (no wire time, see deploy/README.md). Creating them needs root (``ip netns add``); where
that fails the caller gets ``None`` and the reason, and decides how to fall back and say so.
"""

from __future__ import annotations

import os
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass


@dataclass(frozen=True)
class TwoHosts:
    """Command prefixes and addresses of the two namespaces."""

    prefix_a: list[str]
    prefix_b: list[str]
    addr_a: str
    addr_b: str


@contextmanager
def two_namespaces(tag: str = "svd") -> Iterator[tuple[TwoHosts | None, str]]:
    """Yields (hosts, "") or (None, why not). Names carry this process id; all is deleted on exit.

    The subnet is 10.200.<pid % 250>.0/24, so parallel runs on one machine do not collide.
    """
    pid = os.getpid()
    ns_a, ns_b, veth_a, veth_b = f"{tag}A{pid}", f"{tag}B{pid}", f"{tag}a{pid}", f"{tag}b{pid}"
    net = f"10.200.{pid % 250}"
    steps = [
        ["ip", "netns", "add", ns_a], ["ip", "netns", "add", ns_b],
        ["ip", "link", "add", veth_a, "type", "veth", "peer", "name", veth_b],
        ["ip", "link", "set", veth_a, "netns", ns_a], ["ip", "link", "set", veth_b, "netns", ns_b],
        ["ip", "-n", ns_a, "addr", "add", f"{net}.1/24", "dev", veth_a],
        ["ip", "-n", ns_b, "addr", "add", f"{net}.2/24", "dev", veth_b],
        ["ip", "-n", ns_a, "link", "set", veth_a, "up"], ["ip", "-n", ns_b, "link", "set", veth_b, "up"],
        ["ip", "-n", ns_a, "link", "set", "lo", "up"], ["ip", "-n", ns_b, "link", "set", "lo", "up"],
    ]
    try:
        reason = ""
        for step in steps:
            try:
                result = subprocess.run(step, capture_output=True, text=True, timeout=20)
            except (OSError, subprocess.TimeoutExpired) as exc:
                reason = f"{' '.join(step)}: {exc}"
                break
            if result.returncode != 0:
                reason = f"{' '.join(step)}: {result.stderr.strip()}"
                break
        if reason:
            yield None, reason
        else:
            exec_a, exec_b = ["ip", "netns", "exec", ns_a], ["ip", "netns", "exec", ns_b]
            yield TwoHosts(exec_a, exec_b, f"{net}.1", f"{net}.2"), ""
    finally:
        for ns in (ns_a, ns_b):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=20, check=False)
        subprocess.run(["ip", "link", "del", veth_a], capture_output=True, timeout=20, check=False)
