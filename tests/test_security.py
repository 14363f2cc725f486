"""Who may touch the bus: the router profiles of deploy/zenoh/secure with real processes on 127.0.0.1.

The committed JSON5 files are used as they are, except for three things a test must own: the
secrets' folder (/etc/stereovox -> a temporary one), the password placeholders, and the port.
Credentials and certificates are made here, at test time (make-certs.sh, openssl): no key is in
the repository. Denials are silent to the sender (FACTS.md), so every assertion counts what
arrives at a session of another identity.
"""

from __future__ import annotations

import re
import secrets
import shutil
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import zenoh
from conftest import REPO, Processes, free_port, stereovox_cmd, wait_for

from common.bus import declare_alive, open_session, watch_alive
from common.codec import decode, encode
from common.config import BusConfig
from common.errors import BusError
from common.messages import Health, Obstacles, key_for
from common.recording import open_recording
from services.demo import BUNDLED, recording_settings

pytestmark = pytest.mark.reliability

SECURE = REPO / "deploy" / "zenoh" / "secure"
N = 50  # messages per sender
KEY = key_for("tracker/obstacles")


class Profile:
    """The secure JSON5 files copied into ``root`` with working secrets, paths and a free port."""

    def __init__(self, root: Path, port: int) -> None:
        self.root, self.port = root, port
        self.etc = root / "etc"
        self.passwords = {name: secrets.token_urlsafe(12) for name in ("car", "monitor", "guest")}
        (self.etc / "zenoh").mkdir(parents=True)
        (self.etc / "zenoh" / "credentials.txt").write_text(
            "".join(f"{user}:{pw}\n" for user, pw in self.passwords.items())
        )
        make = SECURE / "make-certs.sh"
        for folder, names in ((self.etc / "tls", ["car", "monitor", "guest"]), (root / "rogue", ["car"])):
            subprocess.run(["sh", str(make), str(folder), "IP:127.0.0.1,DNS:localhost", *names],
                           check=True, capture_output=True, timeout=60)
        self.dir = root / "zenoh" / "secure"
        self.dir.mkdir(parents=True)
        for src in SECURE.glob("*.json5"):
            text = src.read_text().replace("/etc/stereovox", str(self.etc)).replace(":7447", f":{port}")
            who = "monitor" if src.name.startswith("monitor") else "car"
            (self.dir / src.name).write_text(text.replace("CHANGE-ME", self.passwords[who]))
        assert not list(root.rglob("*.key")) or all(p.stat().st_mode & 0o077 == 0 for p in root.rglob("*.key"))

    def file(self, name: str) -> Path:
        return self.dir / f"{name}.json5"

    def variant(self, name: str, new_name: str, drop: str = "", replace: tuple[str, str] = ("", "")) -> Path:
        """A copy of a client file without the lines matching ``drop`` (no certificate, ...)."""
        text = self.file(name).read_text()
        if drop:
            text = "\n".join(line for line in text.splitlines() if not re.search(drop, line))
        if replace[0]:
            text = text.replace(*replace)
        text = text.replace("timeout_ms: 30000", "timeout_ms: 3000")  # a refused client retries until then
        path = self.dir / f"{new_name}.json5"
        path.write_text(text)
        return path


@pytest.fixture
def profile(tmp_path: Path) -> Profile:
    return Profile(tmp_path, free_port())


def start_router(processes: Processes, config: Path) -> subprocess.Popen[bytes]:
    router = processes.start(stereovox_cmd("router", "--config", str(config)), "router")
    wait_for(lambda: "router ready" in processes.log(router) or router.poll() is not None, 60, "the router")
    assert router.poll() is None, processes.log(router)
    return router


_OPENED: list[zenoh.Session] = []  # closed after each test, failed or not


def session(config: Path | None = None, **bus: object) -> zenoh.Session:
    opened = open_session(BusConfig(mode=str(bus.pop("mode", "client")), zenoh_config=str(config or ""), **bus))
    _OPENED.append(opened)
    return opened


class Inbox:
    """What one session receives on stereovox/**, by sender tag (the payload's text before '-')."""

    def __init__(self, s: zenoh.Session) -> None:
        self.by_sender: dict[str, int] = {}
        self._lock = threading.Lock()
        self._sub = s.declare_subscriber("stereovox/**", self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        sender = sample.payload.to_bytes().split(b"-")[0].decode(errors="replace")
        with self._lock:
            self.by_sender[sender] = self.by_sender.get(sender, 0) + 1

    def count(self, sender: str) -> int:
        with self._lock:
            return self.by_sender.get(sender, 0)


def send(s: zenoh.Session, tag: str, n: int = N) -> None:
    pub = s.declare_publisher(KEY, congestion_control=zenoh.CongestionControl.BLOCK)
    for i in range(n):
        pub.put(f"{tag}-{i}".encode())
    pub.undeclare()


def refused(config: Path | None = None, **bus: object) -> bool:
    """True when a client session cannot be opened with these settings."""
    try:
        open_session(BusConfig(mode="client", zenoh_config=str(config or ""), **bus)).close()  # type: ignore[arg-type]
    except BusError:
        return True
    return False


def exchange(senders: dict[str, zenoh.Session], inboxes: dict[str, Inbox], reference: str) -> dict[str, dict[str, int]]:
    """Every sender sends N; returns what each inbox got from each sender.

    Absence cannot be awaited, so the ``reference`` sender (authorised) sends last and everyone
    waits for its N messages at every inbox that may read, plus a grace second for stragglers.
    """
    time.sleep(0.5)  # subscriptions reach the router
    for tag, s in senders.items():
        if tag != reference:
            send(s, tag)
    send(senders[reference], reference)
    readers = [box for name, box in inboxes.items() if name in ("car", "monitor")]
    wait_for(lambda: all(box.count(reference) >= N for box in readers), 30, f"{reference}'s messages to arrive")
    time.sleep(1.0)
    return {name: dict(box.by_sender) for name, box in inboxes.items()}


def report(title: str, got: dict[str, dict[str, int]], refused_sessions: dict[str, bool]) -> None:
    print(f"\n{title}: sent {N} per sender; received {got}; refused at open: {refused_sessions}")


@pytest.mark.timeout(120)
def test_usrpwd_profile_lets_the_car_publish_the_monitor_read_and_nobody_else_in(
    processes: Processes, profile: Profile
) -> None:
    start_router(processes, profile.file("router-usrpwd"))
    endpoint = f"tcp/127.0.0.1:{profile.port}"
    sessions = {
        "car": session(profile.file("client-usrpwd")),  # one car session sends, another car one reads
        "car_tx": session(profile.file("client-usrpwd")),
        "monitor": session(profile.file("monitor-usrpwd")),
        "guest": session(user="guest", password=profile.passwords["guest"], connect=[endpoint]),
        "anon_peer": session(mode="peer", connect=[endpoint]),  # a peer opens without logging in
    }
    refusals = {
        "no credentials": refused(connect=[endpoint]),
        "wrong password": refused(user="car", password="not-" + profile.passwords["car"], connect=[endpoint]),
        "monitor's password for car": refused(user="car", password=profile.passwords["monitor"], connect=[endpoint]),
    }
    inboxes = {name: Inbox(s) for name, s in sessions.items() if name != "car_tx"}
    senders = {"car_tx": sessions["car_tx"], "monitor": sessions["monitor"], "guest": sessions["guest"],
               "anon_peer": sessions["anon_peer"]}
    # liveliness too: a monitor cannot pretend a service is up (the launcher trusts these tokens)
    seen_by_car: set[str] = set()
    watch_alive(sessions["car"], "ego", lambda s, up: seen_by_car.add(s) if up else None)
    tokens = [declare_alive(sessions["monitor"], "impostor", "ego"),
              declare_alive(sessions["car_tx"], "tracker", "ego")]  # the control: a car's token arrives
    got = exchange(senders, inboxes, "car_tx")
    wait_for(lambda: "tracker" in seen_by_car, 10, "the car's liveliness token")
    assert "impostor" not in seen_by_car, "the monitor's liveliness token reached the car"
    for token in tokens:
        token.undeclare()
    report("usrpwd", got, refusals)
    assert all(refusals.values()), refusals
    assert got["car"] == {"car_tx": N}, "the car reads the car and nothing the monitor, guest or a peer sent"
    assert got["monitor"].get("car_tx") == N, "the monitor reads what the car publishes"
    assert got["monitor"].get("guest", 0) == got["monitor"].get("anon_peer", 0) == 0
    for outsider in ("guest", "anon_peer"):  # own puts come back locally; nothing arrives through the router
        assert got[outsider].get("car_tx", 0) == 0, f"{outsider} read the car's messages"


@pytest.mark.timeout(120)
def test_mtls_profile_needs_a_certificate_of_the_vehicle_ca(processes: Processes, profile: Profile) -> None:
    start_router(processes, profile.file("router-mtls"))
    guest = profile.variant("client-mtls", "guest-mtls", replace=("/car.", "/guest."))
    sessions = {
        "car": session(profile.file("client-mtls")),
        "car_tx": session(profile.file("client-mtls")),
        "monitor": session(profile.file("monitor-mtls")),
        "guest": session(guest),  # a valid certificate whose name no policy lists
    }
    rogue = profile.variant("client-mtls", "rogue-mtls",
                            replace=(str(profile.etc / "tls" / "car."), str(profile.root / "rogue" / "car.")))
    no_cert = profile.variant("client-mtls", "nocert-mtls", drop="connect_(certificate|private_key)")
    refusals = {
        "no certificate": refused(no_cert),
        "certificate of another CA": refused(rogue),
        "plain tcp": refused(connect=[f"tcp/127.0.0.1:{profile.port}"]),
    }
    inboxes = {name: Inbox(s) for name, s in sessions.items() if name != "car_tx"}
    senders = {"car_tx": sessions["car_tx"], "monitor": sessions["monitor"], "guest": sessions["guest"]}
    got = exchange(senders, inboxes, "car_tx")
    report("mtls", got, refusals)
    assert all(refusals.values()), refusals
    assert got["car"] == {"car_tx": N}
    assert got["monitor"].get("car_tx") == N and got["monitor"].get("guest", 0) == 0
    assert got["guest"].get("car_tx", 0) == 0


@pytest.mark.timeout(240)
def test_the_pipeline_runs_on_the_secure_bus_and_the_monitor_only_reads(
    processes: Processes, profile: Profile, tmp_path: Path
) -> None:
    """deploy/secure.yaml (mTLS + access control) over 6 frames: every stage authenticates and runs,
    the monitor identity sees every service's Health and liveliness, and its puts reach no stage."""
    spec = tmp_path / "secure.yaml"
    shutil.copy(REPO / "deploy" / "secure.yaml", spec)
    frames = 6
    launch = processes.start(
        stereovox_cmd("launch", str(spec), "--log-dir", str(tmp_path / "logs"), "--var", f"port={profile.port}",
                      "--var", f"out={tmp_path}", "--var", f"recording={BUNDLED}", "--var", f"max_frames={frames}",
                      *recording_settings(open_recording(BUNDLED).info())),
        "launch",
    )
    monitor: list[zenoh.Session] = []

    def connected() -> bool:
        try:
            monitor.append(session(profile.file("monitor-mtls")))
        except BusError:
            return launch.poll() is not None
        return True

    wait_for(connected, 90, "the secure router")
    assert launch.poll() is None, processes.log(launch)
    alive: set[str] = set()
    watch_alive(monitor[0], "ego", lambda s, up: alive.add(s) if up else None)
    health: dict[str, Health] = {}
    monitor[0].declare_subscriber(key_for("health/*"), lambda s: health.update(
        {(h := decode(s.payload.to_bytes(), Health)).service: h}))
    last_obstacles: list[bytes] = []
    monitor[0].declare_subscriber(KEY, lambda s: last_obstacles.append(s.payload.to_bytes()))
    replayed = re.compile(r"camera_replay\s+exited with 0")
    wait_for(lambda: bool(replayed.search(processes.log(launch))) or launch.poll() is not None, 180,
             "the replay to finish")
    assert launch.poll() is None, processes.log(launch)
    stages = ("stereo_depth", "odometry", "voxel_mapper", "tracker")
    wait_for(lambda: all(s in health and health[s].frames_out >= frames for s in stages), 30, "every stage's Health")
    car = session(profile.file("client-mtls"))
    # the real `stereovox monitor`, as deploy/README.md tells one to start it; its snapshot needs an
    # Obstacles message, so a car session repeats the last frame's until the monitor has printed
    dashboard = processes.start(stereovox_cmd(
        "monitor", "--once", "--timeout", "60", "--connect", f"tls/127.0.0.1:{profile.port}",
        "--set", f"bus.zenoh_config={profile.file('monitor-mtls')}"), "monitor")
    # on a loaded machine the six frames' obstacles can all be out before the monitor's subscriber is:
    # then the car repeats an empty frame of its own, which the snapshot shows as well
    repeated = last_obstacles[-1] if last_obstacles else encode(Obstacles(frame_id=frames, stamp_ns=time.time_ns()))
    wait_for(lambda: car.put(KEY, repeated) or dashboard.poll() is not None, 90, "the monitor's snapshot",
             interval=0.5)
    assert dashboard.returncode == 0, processes.log(dashboard)
    assert all(s in processes.log(dashboard) for s in stages), processes.log(dashboard)
    # N junk puts on the tracker's input from the monitor (denied), then N from a car session (the
    # control: they arrive, so the tracker's decode-error count shows exactly who got through)
    forged = key_for("voxel_mapper/clusters")
    for _ in range(N):
        monitor[0].put(forged, b"forged by the monitor")
    time.sleep(0.5)
    for _ in range(N):
        car.put(forged, b"junk from the car")
    wait_for(lambda: health["tracker"].decode_errors >= N, 30, "the car's junk to be counted")
    time.sleep(1.5)
    counted = health["tracker"].decode_errors
    assert processes.stop(launch, signal.SIGINT, timeout=60) == 0, processes.log(launch)[-3000:]
    print(f"\nsecure pipeline: alive seen by monitor {sorted(alive)}; tracker decode_errors {counted} after "
          f"{N} puts from the monitor and {N} from the car")
    assert {"recorder", *stages} <= alive
    assert counted == N, f"the tracker counted {counted} bad messages: {counted - N} of the monitor's got through"
    run = open_recording(tmp_path / "run.mcap")
    obstacles = run.by_topic("tracker/obstacles")
    assert sorted(obstacles) == list(range(frames))
    assert all(np.isfinite(m.ego_pose).all() for m in obstacles.values())
    assert sum(1 for _ in run.messages()) > 0 and run.decode_errors == N, run.decode_errors


@pytest.fixture(autouse=True)
def _close_sessions_and_check_no_secrets() -> Iterator[None]:
    yield
    while _OPENED:
        _OPENED.pop().close()
    assert not [p for p in SECURE.rglob("*") if p.suffix in (".key", ".pem", ".txt")], "secrets in deploy/"
