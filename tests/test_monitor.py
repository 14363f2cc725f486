"""`stereovox monitor`: a read-only client that attaches to a running vehicle from outside it."""

from __future__ import annotations

import re
import subprocess
import threading
from pathlib import Path

import pytest
import zenoh
from conftest import REPO, Processes, free_port, stereovox_cmd, wait_for

from common.bus import open_session
from common.config import BusConfig
from services.demo import BUNDLED

SERVICES = ("camera_replay", "stereo_depth", "odometry", "voxel_mapper", "tracker", "recorder")
ROW = "\u2502"  # rich's table column separator


def _recording(request: pytest.FixtureRequest) -> Path:
    """The bundled urban recording, or a short simulated one where it has not been made yet."""
    return BUNDLED if BUNDLED.is_file() else request.getfixturevalue("urban_recording")


@pytest.mark.timeout(240)
def test_monitor_once_lists_every_service_and_an_obstacle_of_a_running_demo(
    processes: Processes, tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    recording = _recording(request)
    demo = processes.start(
        stereovox_cmd("demo", "--recording", str(recording), "--max-frames", "40", "--out", str(tmp_path / "demo")),
        "demo",
    )
    found: list[str] = []

    def router_printed() -> bool:
        found[:] = re.findall(r"demo: router at (tcp/127\.0\.0\.1:\d+)", processes.log(demo))
        return bool(found) or demo.poll() is not None

    wait_for(router_printed, 150, "the demo to print its router endpoint")
    assert found, f"demo ended without printing its router:\n{processes.log(demo)[-2000:]}"
    proc = subprocess.run(
        stereovox_cmd("monitor", "--connect", found[0], "--once", "--timeout", "60"),
        capture_output=True, text=True, cwd=REPO, timeout=90,
    )
    assert proc.returncode == 0, f"monitor failed:\n{proc.stdout}\n{proc.stderr}"
    for service in SERVICES:
        assert re.search(rf"{service}\s*{ROW}\s*alive\s*{ROW}", proc.stdout), f"{service} not alive in:\n{proc.stdout}"
    rows = re.findall(rf"{ROW}\s*\d+\s*{ROW}\s*(tracked|acceptance|ghost)\s*{ROW}\s*(moving|stationary)\s*{ROW}",
                      proc.stdout)
    assert rows, f"no obstacle listed:\n{proc.stdout}"
    assert re.search(r"obstacles of frame \d+", proc.stdout)


@pytest.mark.timeout(60)
def test_monitor_puts_nothing_on_the_bus_and_says_what_it_missed(processes: Processes) -> None:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    router = processes.start(stereovox_cmd("router", "--listen", endpoint), "router")
    heard: list[str] = []
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        with lock:
            heard.append(str(sample.key_expr))

    bus = BusConfig(mode="client", connect=[endpoint])
    wait_for(lambda: _opens(bus) or router.poll() is not None, 30, "the router to accept clients")
    with open_session(bus) as session:
        sub = session.declare_subscriber("stereovox/**", on_sample)
        tokens = session.liveliness().declare_subscriber("stereovox/**", on_sample)
        proc = subprocess.run(
            stereovox_cmd("monitor", "--connect", endpoint, "--once", "--timeout", "3"),
            capture_output=True, text=True, cwd=REPO, timeout=45,
        )
        sub.undeclare()
        tokens.undeclare()
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "still missing: a liveliness token" in proc.stderr
    assert "obstacles (none received yet)" in proc.stdout
    assert heard == [], f"the monitor published or declared a token on {heard}"


def _opens(bus: BusConfig) -> bool:
    try:
        with open_session(bus):
            return True
    except Exception:  # the router is not listening yet
        return False
