"""Deploying across computers: ``launch --check``, two real hosts in network namespaces, supervision.

The two-computer test joins two network namespaces with a veth pair carrying this test's own
addresses (10.200.<pid % 250>.1 and .2), runs each half of deploy/two-computers.yaml with
``launch --host`` inside its namespace, and compares the obstacles the recorder on the second
host wrote with a ``stereovox process`` run, frame by frame. Where namespaces cannot be made it
runs both halves on 127.0.0.1 and says so on the terminal; it never passes silently.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO, Processes, free_port, stereovox_cmd, wait_for

from common.bus import open_session, subscribe, watch_alive
from common.config import BusConfig
from common.errors import ConfigError
from common.evaluation.evaluate import evaluate_recording
from common.messages import Obstacles, key_for
from common.recording import open_recording
from services.launch_spec import load_spec
from services.netns import two_namespaces
from services.pipeline import process_file

RECORDING = REPO / "recordings" / "urban.mcap"
FRAMES = 10
DEPLOY = REPO / "deploy"


def _check(spec: Path, *variables: str) -> subprocess.CompletedProcess[str]:
    args = [a for v in variables for a in ("--var", v)]
    return subprocess.run(
        stereovox_cmd("launch", str(spec), "--check", *args), cwd=REPO, capture_output=True, text=True, timeout=60
    )


def _spec_variant(tmp_path: Path, base: str, name: str, change: dict) -> Path:
    """A copy of a deploy spec with some services changed; Zenoh files stay those beside the original."""
    raw = yaml.safe_load((DEPLOY / base).read_text())
    raw["zenoh"] = {role: str(DEPLOY / f) for role, f in raw.get("zenoh", {}).items()}
    if "extends" in raw:
        raw["extends"] = str(DEPLOY / raw["extends"])
    for service, fields in change.items():
        if fields is None:
            raw["services"].pop(service)
        else:
            raw["services"][service].update(fields)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(raw))
    return path


# ---------------------------------------------------------------- --check


def test_check_accepts_every_deploy_spec() -> None:
    values = ["port=7447", "out=/tmp/x", "recording=r.mcap", "max_frames=3", "addr_a=10.1.0.1", "addr_b=10.1.0.2"]
    for spec in sorted(DEPLOY.glob("*.yaml")):
        proc = _check(spec, *values)
        assert proc.returncode == 0, f"{spec.name}: {proc.stderr}"
        assert "OK" in proc.stdout


def test_a_spec_extends_another_and_names_only_what_it_changes(tmp_path: Path) -> None:
    variant = tmp_path / "variant.yaml"
    variant.write_text(yaml.safe_dump({
        "extends": str(DEPLOY / "local.yaml"),
        "name": "variant",
        "services": {"tracker": {"command": ["run", "tracker", "--set", "tracker.gate=2.0"],
                                 "inputs": {"odometry/ego": {"queue": "fifo", "schema": "stereovox.EgoMotion/1"}}}},
    }))
    variables = {"port": "1", "out": "o", "recording": "r", "max_frames": "1"}
    base, spec = load_spec(DEPLOY / "local.yaml", variables), load_spec(variant, variables)
    assert spec.name == "variant" and sorted(spec.services) == sorted(base.services)
    assert spec.services["tracker"].command == ["run", "tracker", "--set", "tracker.gate=2.0"]  # lists: replaced
    assert spec.services["tracker"].inputs == base.services["tracker"].inputs  # mappings: merged key by key
    assert spec.services["odometry"] == base.services["odometry"] and spec.zenoh == base.zenoh
    broken = tmp_path / "broken.yaml"
    broken.write_text("extends: nowhere.yaml\n")
    with pytest.raises(ConfigError, match=r"broken\.yaml: extends nowhere\.yaml: cannot read"):
        load_spec(broken, variables)


def test_check_rejects_a_key_without_publisher(tmp_path: Path) -> None:
    spec = _spec_variant(tmp_path, "local.yaml", "no-odometry.yaml", {"odometry": None})
    proc = _check(spec, "port=1", "out=o", "recording=r", "max_frames=1")
    assert proc.returncode == 2
    for service in ("voxel_mapper", "tracker"):
        assert f"service {service}: input odometry/ego has no publisher" in proc.stderr


def test_check_rejects_a_schema_version_mismatch(tmp_path: Path) -> None:
    inputs = {
        "voxel_mapper/clusters": {"schema": "stereovox.Clusters/2", "queue": "fifo"},
        "odometry/ego": {"schema": "stereovox.EgoMotion/1", "queue": "fifo"},
    }
    spec = _spec_variant(tmp_path, "local.yaml", "v2.yaml", {"tracker": {"inputs": inputs}})
    proc = _check(spec, "port=1", "out=o", "recording=r", "max_frames=1")
    assert proc.returncode == 2
    assert "service tracker: input voxel_mapper/clusters expects stereovox.Clusters/2" in proc.stderr
    assert "voxel_mapper publishes stereovox.Clusters/1" in proc.stderr


def test_check_rejects_inconsistent_hosts_and_endpoints(tmp_path: Path) -> None:
    raw = yaml.safe_load((DEPLOY / "two-computers.yaml").read_text())
    raw["zenoh"] = {}
    raw["hosts"]["perception-b"] = {}
    raw["services"]["odometry"]["inputs"]["camera/stereo"]["queue"] = "newest"
    raw["services"]["odometry"]["command"] = ["run", "odometry", "--policy", "fifo"]
    spec = tmp_path / "bad-hosts.yaml"
    spec.write_text(yaml.safe_dump(raw))
    proc = _check(spec, "port=1", "out=o", "recording=r", "max_frames=1", "addr_a=10.1.0.1", "addr_b=10.1.0.2")
    assert proc.returncode == 2
    assert "host perception-b: no address" in proc.stderr
    assert "service odometry: command says --policy fifo but its inputs say newest" in proc.stderr
    wrong = _check(DEPLOY / "two-computers.yaml", "port=1", "out=o", "recording=r", "max_frames=1",
                   "addr_a=127.0.0.1", "addr_b=10.1.0.2")
    assert wrong.returncode == 2 and "router: listens on loopback 127.0.0.1" in wrong.stderr


def test_check_compares_the_spec_with_what_the_stages_read(tmp_path: Path) -> None:
    """A graph consistent on paper, but the voxel mapper's code reads stereo_depth/points, not a renamed key."""
    raw = yaml.safe_load((DEPLOY / "local.yaml").read_text())
    raw["zenoh"] = {}
    stereo, mapper = raw["services"]["stereo_depth"], raw["services"]["voxel_mapper"]
    stereo["outputs"]["stereo_depth/cloud"] = stereo["outputs"].pop("stereo_depth/points")
    mapper["inputs"]["stereo_depth/cloud"] = mapper["inputs"].pop("stereo_depth/points")
    spec = tmp_path / "renamed.yaml"
    spec.write_text(yaml.safe_dump(raw))
    proc = _check(spec, "port=1", "out=o", "recording=r", "max_frames=1")
    assert proc.returncode == 2
    assert "service voxel_mapper: the code reads stereo_depth/points, the spec does not list it" in proc.stderr
    assert "service stereo_depth: output stereo_depth/cloud is not written by stage stereo_depth" in proc.stderr


# ---------------------------------------------------------------- two hosts


@contextmanager
def two_hosts() -> Iterator[tuple[list[str], list[str], str, str] | None]:
    """Two namespaces joined by a veth pair: (prefix_a, prefix_b, addr_a, addr_b), or None if not possible.

    Every name carries this process id, and the namespaces are deleted whatever happens.
    """
    with two_namespaces("svd") as (hosts, reason):
        if hosts is None:
            print(f"network namespaces unavailable ({reason})")
            yield None
        else:
            yield hosts.prefix_a, hosts.prefix_b, hosts.addr_a, hosts.addr_b


def _obstacle_rows(msg: Obstacles) -> list[tuple]:
    return [
        (o.id, o.state, o.moving, o.age, *np.round(o.centroid, 9), *np.round(o.velocity, 9)) for o in msg.obstacles
    ]


@pytest.mark.timeout(300)
def test_two_computers_match_one_process(
    processes: Processes, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert RECORDING.is_file(), f"bundled recording {RECORDING} is missing"
    spec = DEPLOY / "two-computers.yaml"
    out = tmp_path / "out"
    with two_hosts() as hosts:
        if hosts is None:
            prefix_a, prefix_b, addr_a, addr_b = [], [], "127.0.0.1", "127.0.0.1"
            how = "FELL BACK to two launch processes on 127.0.0.1 (no network namespaces here)"
        else:
            prefix_a, prefix_b, addr_a, addr_b = hosts
            how = f"across two network namespaces joined by a veth pair ({addr_a} <-> {addr_b})"
        with capsys.disabled():
            print(f"\ntest_two_computers: ran {how}")
        variables = [f"addr_a={addr_a}", f"addr_b={addr_b}", f"port={free_port()}", f"out={out}",
                     f"recording={RECORDING}", f"max_frames={FRAMES}"]
        var_args = [a for v in variables for a in ("--var", v)]
        launches = {}
        try:
            # the second computer first: its clients wait for a router that is not up yet
            for host, prefix in (("perception-b", prefix_b), ("perception-a", prefix_a)):
                cmd = [*prefix, *stereovox_cmd("launch", str(spec), "--host", host, "--log-dir",
                                               str(tmp_path / host), *var_args)]
                launches[host] = processes.start(cmd, f"launch-{host}")
            replay_log = tmp_path / "perception-a" / "camera_replay.log"
            wait_for(lambda: (replay_log.is_file() and "replay done" in replay_log.read_text())
                     or any(p.poll() is not None for p in launches.values()), 240, "the replay to finish")
            assert all(p.poll() is None for p in launches.values()), {h: processes.log(p) for h, p in launches.items()}
            assert "0 lockstep timeouts" in replay_log.read_text(), replay_log.read_text()
            # a loose bound: on a loaded 2-core machine a launch and its children took over 20 s to stop
            assert processes.stop(launches["perception-b"], timeout=60.0) == 0, processes.log(launches["perception-b"])
            assert processes.stop(launches["perception-a"], timeout=60.0) == 0, processes.log(launches["perception-a"])
            for host, proc in launches.items():
                stopped = processes.log(proc).strip().splitlines()[-1]
                assert "stopped:" in stopped and "exit -" not in stopped, f"{host}: a child died by signal: {stopped}"
        finally:
            for proc in launches.values():
                processes.stop(proc, signal.SIGKILL, timeout=5)
    local = tmp_path / "process.mcap"
    assert process_file(RECORDING, local, max_frames=FRAMES, with_frames=False) == FRAMES
    distributed = open_recording(out / "run.mcap").by_topic("tracker/obstacles")
    in_process = open_recording(local).by_topic("tracker/obstacles")
    assert sorted(distributed) == sorted(in_process) == list(range(FRAMES))
    for frame_id in sorted(in_process):
        assert _obstacle_rows(distributed[frame_id]) == _obstacle_rows(in_process[frame_id]), frame_id
    run_report, local_report = evaluate_recording(out / "run.mcap"), evaluate_recording(local)
    assert run_report["frames"] == local_report["frames"] == FRAMES
    assert run_report["moving"] == local_report["moving"]


# ---------------------------------------------------------------- supervision


@pytest.mark.timeout(240)
def test_killed_service_comes_back_and_the_pipeline_goes_on(
    processes: Processes, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """SIGKILL the tracker under ``launch``: its token comes back and new obstacles arrive (bound 15 s)."""
    waits = "stereo_depth,odometry,voxel_mapper,tracker"
    paced = {"recorder": None,
             "camera_replay": {"command": ["replay", "{recording}", "--rate", "0.5", "--loop", "--wait-for", waits]}}
    spec = _spec_variant(tmp_path, "live.yaml", "paced.yaml", paced)
    port = free_port()
    launch = processes.start(stereovox_cmd("launch", str(spec), "--log-dir", str(tmp_path / "logs"),
                                           "--status-every", "1", "--var", f"port={port}",
                                           "--var", f"recording={RECORDING}", "--var", f"out={tmp_path}"), "launch")
    seen: list[tuple[float, int]] = []  # (arrival, frame id) of every obstacles report
    tokens: list[tuple[float, bool]] = []
    lock = threading.Lock()
    wait_for(lambda: "tracker" in _pids(processes, launch) or launch.poll() is not None, 60, "the tracker to start")
    bus = BusConfig(mode="client", connect=[f"tcp/127.0.0.1:{port}"], zenoh_config=str(DEPLOY / "zenoh/client.json5"))
    with open_session(bus) as session:
        sub = subscribe(session, key_for("tracker/obstacles"), Obstacles, "fifo", depth=256)

        def on_alive(service: str, up: bool) -> None:
            if service == "tracker":
                with lock:
                    tokens.append((time.monotonic(), up))

        watcher = watch_alive(session, "ego", on_alive)

        def drain() -> int:
            while (item := sub.recv(0)) is not None:
                seen.append((time.monotonic(), item.msg.frame_id))
            return len(seen)

        wait_for(lambda: drain() >= 3 or launch.poll() is not None, 120, "obstacles before the kill")
        assert launch.poll() is None, processes.log(launch)
        pid = _pids(processes, launch)["tracker"]
        killed_at = time.monotonic()
        os.kill(pid, signal.SIGKILL)
        last_before = seen[-1][1]
        wait_for(lambda: any(up and t > killed_at for t, up in list(tokens)), 15, "the tracker's token to come back")
        back_at = next(t for t, up in list(tokens) if up and t > killed_at)
        wait_for(lambda: drain() and seen[-1][0] > back_at, 15, "obstacles from the restarted tracker")
        first_after = next((t, f) for t, f in seen if t > back_at)
        watcher.undeclare()
        sub.close()
    new_pid = _pids(processes, launch)["tracker"]
    assert new_pid != pid
    before = [f for t, f in seen if t < killed_at]
    normal_gap = float(np.median(np.diff(before))) if len(before) > 1 else 1.0
    with capsys.disabled():
        print(f"\nrestart: token back {back_at - killed_at:.2f} s after SIGKILL, first new obstacles after "
              f"{first_after[0] - killed_at:.2f} s; frame ids {last_before} -> {first_after[1]} "
              f"(usual step {normal_gap:g})")
    wait_for(lambda: re.search(r"tracker=up\(pid \d+, r1, exit -9\)", processes.log(launch)) is not None, 15,
             "a status line showing the restart")
    assert processes.stop(launch) == 0
    assert re.search(r"tracker\s+alive again [\d.]+ s after it died", processes.log(launch))


def _pids(processes: Processes, launch: subprocess.Popen[bytes]) -> dict[str, int]:
    """The newest pid the launcher logged for each service."""
    return {m.group(1): int(m.group(2)) for m in re.finditer(r"(\w+)\s+started pid (\d+)", processes.log(launch))}


# ---------------------------------------------------------------- Zenoh files


def test_router_takes_its_endpoints_from_the_json5_file() -> None:
    from services.router import router_bus

    bus = router_bus([], [], str(DEPLOY / "zenoh" / "router.json5"), [])
    assert bus.mode == "router" and bus.listen == ["tcp/127.0.0.1:7447"]
    assert router_bus(["tcp/127.0.0.1:9"], [], str(DEPLOY / "zenoh" / "router.json5"), []).listen == ["tcp/127.0.0.1:9"]


@pytest.mark.timeout(60)
def test_a_client_started_before_the_router_waits_for_it(processes: Processes) -> None:
    """client.json5 keeps trying: the second computer may boot before the router's."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    bus = BusConfig(mode="client", connect=[endpoint], zenoh_config=str(DEPLOY / "zenoh" / "client.json5"))
    opened: list[float] = []

    def client() -> None:
        with open_session(bus):
            opened.append(time.monotonic())

    thread = threading.Thread(target=client, daemon=True)
    thread.start()
    time.sleep(0.5)  # the client is now retrying against a closed port (the point of the test, not a wait)
    assert not opened
    router = processes.start(stereovox_cmd("router", "--config", str(DEPLOY / "zenoh" / "router.json5"),
                                           "--listen", endpoint), "router")
    thread.join(30)
    assert opened, f"the client gave up before the router came: {processes.log(router)}"
    assert processes.stop(router) == 0
