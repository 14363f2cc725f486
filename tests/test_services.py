"""The stage shell: joins by frame id, one output per input frame, timing trails, health, real processes."""

from __future__ import annotations

import dataclasses
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterator

import msgpack
import numpy as np
import pytest
import zenoh
from conftest import Processes, free_port, stereovox_cmd, wait_for

from common.bus import Publisher, open_session, subscribe, watch_alive
from common.codec import encode
from common.config import BusConfig, Config
from common.errors import InputError
from common.messages import (
    Calibration,
    Clusters,
    EgoMotion,
    Health,
    Obstacles,
    PointCloud,
    StereoFrame,
    key_for,
    now_ns,
)
from services.join import FrameJoiner
from services.shell import Stage, StageLoop


def ego(frame_id: int, epoch: int = 7) -> EgoMotion:
    pose = np.eye(4)
    pose[0, 3] = 0.5 * frame_id
    return EgoMotion(frame_id=frame_id, stamp_ns=1_000 + frame_id, pose=pose, valid=True, world_epoch=epoch,
                     timing=[("odometry", 10 * frame_id, 10 * frame_id + 3)])


def clusters(frame_id: int, epoch: int = 7) -> Clusters:
    return Clusters(frame_id=frame_id, stamp_ns=1_000 + frame_id, voxel_edge=0.25, world_epoch=epoch,
                    timing=[("voxel_mapper", 10 * frame_id + 1, 10 * frame_id + 4)])


# ----------------------------------------------------------------------------- the join, as a pure unit


def test_joiner_pairs_inputs_by_frame_id_in_any_order() -> None:
    join = FrameJoiner(["points", "ego"])
    assert join.add("ego", ego(1)) is None
    assert join.add("ego", ego(2)) is None
    assert join.add("points", clusters(3)) is None
    done = join.add("points", clusters(1))
    assert done is not None and done["ego"].frame_id == 1 and done["points"].frame_id == 1
    done = join.add("ego", ego(3))
    assert done is not None and {m.frame_id for m in done.values()} == {3}
    # frame 2 can no longer complete (its points were dropped upstream): evicted, and counted
    assert join.pending() == 0 and join.evicted == 1


def test_joiner_stays_bounded_and_counts_evictions() -> None:
    join = FrameJoiner(["points", "ego"], capacity=4)
    for k in range(10):
        assert join.add("ego", ego(k)) is None
    assert join.pending() == 4 and join.pending("ego") == 4 and join.evicted == 6
    assert join.add("points", clusters(2)) is None  # evicted long ago: waits as a new partial
    done = join.add("points", clusters(9))
    assert done is not None and done["ego"].frame_id == 9
    with pytest.raises(ValueError, match="unknown input"):
        join.add("clusters", clusters(1))


def test_an_optional_input_is_taken_when_there_and_never_waited_for() -> None:
    join = FrameJoiner(["frame", "ins"], optional=["ins"])
    assert join.add("ins", ego(1)) is None  # the sample first, as a replay sends it
    done = join.add("frame", clusters(1))
    assert done is not None and set(done) == {"frame", "ins"} and done["ins"].frame_id == 1
    done = join.add("frame", clusters(2))  # no sample for frame 2: it goes on without one
    assert done is not None and set(done) == {"frame"} and join.without_optional == 1
    assert join.add("ins", ego(2)) is None and join.pending() == 1  # too late for its frame: it waits ...
    join.add("ins", ego(4))
    done = join.add("frame", clusters(4))
    assert done is not None and set(done) == {"frame", "ins"} and join.without_optional == 1
    assert join.pending() == 0 and join.evicted == 1  # ... and is evicted once a newer frame is done
    with pytest.raises(ValueError, match="some, not all"):
        FrameJoiner(["ins"], optional=["ins"])


def test_single_input_frames_complete_at_once() -> None:
    join = FrameJoiner(["frame"])
    out = join.add("frame", ego(5))
    assert out is not None and out["frame"].frame_id == 5 and join.pending() == 0


# ----------------------------------------------------------------------------- the shell on a real bus, in-process


@pytest.fixture
def router() -> Iterator[tuple[zenoh.Session, int]]:
    port = free_port()
    with open_session(BusConfig(mode="router", listen=[f"tcp/127.0.0.1:{port}"])) as session:
        yield session, port


def trivial_stage() -> Stage:
    """Clusters + ego -> Obstacles; fails (InputError) on frame 3, which must yield an empty output."""

    def process(c: Clusters, e: EgoMotion) -> tuple[Obstacles]:
        if c.frame_id == 3:
            raise InputError("frame 3 is poisoned")
        return (Obstacles(frame_id=c.frame_id, stamp_ns=c.stamp_ns, world_epoch=e.world_epoch, ego_pose=e.pose),)

    def empty(c: Clusters, e: EgoMotion) -> tuple[Obstacles]:
        return (Obstacles(frame_id=c.frame_id, stamp_ns=c.stamp_ns, world_epoch=-1),)

    return Stage(name="tracker", inputs={"voxel_mapper/clusters": Clusters, "odometry/ego": EgoMotion},
                 outputs=("tracker/obstacles",), process=process, empty=empty)


def collect(sub: object, n: int, timeout: float, what: str) -> list[object]:
    """Receive ``n`` messages from a bus subscriber (its ``recv``), failing after ``timeout``."""
    got: list[object] = []

    def more() -> bool:
        item = sub.recv(0.1)  # type: ignore[attr-defined]
        if item is not None:
            got.append(item.msg)
        return len(got) >= n

    wait_for(more, timeout, what, interval=0.0)
    return got


@pytest.mark.timeout(60)
def test_stage_loop_joins_stamps_and_answers_every_frame(router: tuple[zenoh.Session, int]) -> None:
    session, port = router
    with open_session(BusConfig(mode="client", connect=[f"tcp/127.0.0.1:{port}"])) as client:
        loop = StageLoop(trivial_stage(), Config(), client, policy="fifo")
        out = subscribe(session, key_for("tracker/obstacles"), Obstacles, "fifo", depth=64)
        pub_c, pub_e = Publisher(session, key_for("voxel_mapper/clusters")), Publisher(session, key_for("odometry/ego"))
        stop = threading.Event()
        worker = threading.Thread(target=lambda: [loop.step() for _ in iter(stop.is_set, True)], daemon=True)
        worker.start()
        try:
            wait_for(lambda: pub_c.matched() and pub_e.matched(), 30, "the shell's subscribers")
            for k in range(8):  # ego first for odd frames, clusters first for even ones
                pairs = [(pub_e, ego(k)), (pub_c, clusters(k))]
                for pub, msg in pairs if k % 2 else reversed(pairs):
                    pub.put(msg)
            results = collect(out, 8, 30, "eight obstacles")
        finally:
            stop.set()
            worker.join(5)
            loop.close()
    assert [m.frame_id for m in results] == list(range(8))  # one output per frame, in order
    assert [m.world_epoch for m in results] == [7, 7, 7, -1, 7, 7, 7, 7]  # frame 3: the empty output
    assert loop.health.errors == 1 and "poisoned" in loop.health.last_error
    for m in results:
        assert [t[0] for t in m.timing] == ["odometry", "voxel_mapper", "tracker"], m.timing
        assert m.timing[-1][1] <= m.timing[-1][2]
    report = loop.health.report()
    assert (report.frames_in, report.frames_out, report.errors, report.decode_errors) == (16, 8, 1, 0)
    assert report.detail["join_evicted"] == 0 and report.detail["join_pending"] == 0



@pytest.mark.timeout(60)
def test_newest_policy_processes_the_latest_frame_and_counts_the_skipped(router: tuple[zenoh.Session, int]) -> None:
    session, port = router
    with open_session(BusConfig(mode="client", connect=[f"tcp/127.0.0.1:{port}"])) as client:
        loop = StageLoop(trivial_stage(), Config(), client, policy="newest")
        out = subscribe(session, key_for("tracker/obstacles"), Obstacles, "fifo", depth=64)
        pub_c, pub_e = Publisher(session, key_for("voxel_mapper/clusters")), Publisher(session, key_for("odometry/ego"))
        try:
            wait_for(lambda: pub_c.matched() and pub_e.matched(), 30, "the shell's subscribers")
            for k in range(5, 10):  # the stage is busy elsewhere: five frames pile up
                pub_c.put(clusters(k))
                pub_e.put(ego(k))
            wait_for(lambda: all(s.received == 5 for s in loop.subs.values()), 30, "the five frames to arrive")
            wait_for(loop.step, 10, "one frame processed")
            results = collect(out, 1, 30, "the newest frame's obstacles")
            assert not loop.step(0.2)  # nothing older is left to process
        finally:
            loop.close()
    assert [m.frame_id for m in results] == [9]
    report = loop.health.report()
    assert (report.frames_in, report.frames_out, report.dropped) == (10, 1, 8)
    assert report.detail["inputs"][key_for("odometry/ego")]["dropped"] == 4

# ----------------------------------------------------------------------------- real service processes


def start_service(processes: Processes, name: str, port: int, *extra: str) -> subprocess.Popen[bytes]:
    cmd = stereovox_cmd("run", name, "--mode", "client", "--connect", f"tcp/127.0.0.1:{port}", *extra)
    return processes.start(cmd, name)


def alive_set(session: zenoh.Session) -> set[str]:
    """Services whose liveliness tokens are up, kept current by a subscriber on the session."""
    alive: set[str] = set()
    watch_alive(session, "ego", lambda service, up: alive.add(service) if up else alive.discard(service))
    return alive


@pytest.mark.reliability
@pytest.mark.timeout(120)
def test_tracker_process_drops_malformed_input_counts_it_and_keeps_answering(
    router: tuple[zenoh.Session, int], processes: Processes
) -> None:
    session, port = router
    alive = alive_set(session)
    out = subscribe(session, key_for("tracker/obstacles"), Obstacles, "fifo", depth=64)
    health = subscribe(session, key_for("health/tracker"), Health, "newest")
    proc = start_service(processes, "tracker", port, "--policy", "fifo")
    wait_for(lambda: "tracker" in alive or proc.poll() is not None, 60, "the tracker's liveliness token")
    assert proc.poll() is None, processes.log(proc)
    pub_c, pub_e = Publisher(session, key_for("voxel_mapper/clusters")), Publisher(session, key_for("odometry/ego"))
    wait_for(lambda: pub_c.matched() and pub_e.matched(), 30, "the tracker's subscribers")
    good = encode(clusters(0))
    junk = [
        b"",
        b"\xc1 not msgpack",
        good[: len(good) // 2],  # truncated
        encode(ego(0)),  # a valid message of the wrong type for this key
        good.replace(b"Clusters", b"Clustery"),  # unknown schema
        msgpack.packb({"schema": "Clusters", "v": 99, "body": {}}),  # unknown version
    ]
    for k in range(6):
        for bad in junk:
            pub_c.put(bad)
        pub_e.put(b"\x93\x01\x02")  # a msgpack array, not an envelope
        pub_c.put(clusters(k))
        pub_e.put(ego(k))
    results = collect(out, 6, 60, "six obstacles despite the junk")
    assert [m.frame_id for m in results] == list(range(6))
    assert all(m.timing[-1][0] == "tracker" and m.world_epoch == 7 for m in results)
    expected_errors = 6 * (len(junk) + 1)
    latest: list[Health] = []

    def counted() -> bool:
        item = health.recv(0.2)
        if item is not None:
            latest[:] = [item.msg]
        return bool(latest) and latest[0].decode_errors >= expected_errors and latest[0].frames_out >= 6

    wait_for(counted, 30, "a Health report counting the malformed messages")
    report = latest[0]
    assert report.decode_errors == expected_errors and report.frames_in == 12 and report.errors == 0
    assert report.detail["inputs"][key_for("voxel_mapper/clusters")]["decode_errors"] == 6 * len(junk)
    assert report.detail["core"]["frames"] == 6  # the real tracker core saw every frame
    assert proc.poll() is None
    assert processes.stop(proc, signal.SIGINT) == 0
    log = processes.log(proc)
    assert "tracker ready" in log and "malformed" in log
    wait_for(lambda: "tracker" not in alive, 10, "the liveliness token to go away")


def stereo_frame(k: int, width: int = 320, height: int = 240) -> StereoFrame:
    """A textured wall 9.45 m ahead (20 px of disparity), seen by a rig 1.65 m above the road."""
    rng = np.random.default_rng(1)
    texture = rng.integers(0, 256, (height, width + 20, 3), dtype=np.uint8)
    cam_to_vehicle = np.array([[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 1.65], [0, 0, 0, 1]], dtype=np.float64)
    calib = Calibration(fx=350.0, fy=350.0, cx=width / 2, cy=height / 2, baseline=0.54, width=width, height=height,
                        cam_to_vehicle=cam_to_vehicle)
    stamp = now_ns()
    return StereoFrame(frame_id=k, stamp_ns=1_000_000_000 + k * 100_000_000, left=texture[:, :width].copy(),
                       right=texture[:, 20:].copy(), calib=calib, timing=[("camera_replay", stamp, stamp)])


@pytest.mark.timeout(240)
def test_four_stage_processes_answer_every_frame_in_lockstep_with_the_whole_trail(
    router: tuple[zenoh.Session, int], processes: Processes
) -> None:
    """Frame 1 is blank (degenerate), frame 2 is too small to match (stereo_depth raises): both answered."""
    session, port = router
    stages = ("stereo_depth", "odometry", "voxel_mapper", "tracker")
    alive = alive_set(session)
    out = subscribe(session, key_for("tracker/obstacles"), Obstacles, "fifo", depth=16)
    clouds = subscribe(session, key_for("stereo_depth/points"), PointCloud, "fifo", depth=16)
    health = {s: subscribe(session, key_for(f"health/{s}"), Health, "newest") for s in stages}
    started_ms = time.time_ns() // 1_000_000
    short = {"tracker": ["--max-frames", "5"]}  # the tracker ends on its own after five frames
    procs = {s: start_service(processes, s, port, "--policy", "fifo", *short.get(s, [])) for s in stages}
    wait_for(lambda: set(stages) <= alive or any(p.poll() is not None for p in procs.values()), 120,
             "all four stages' liveliness tokens")
    assert all(p.poll() is None for p in procs.values()), {s: processes.log(p)[-2000:] for s, p in procs.items()}
    camera = Publisher(session, key_for("camera/stereo"))
    frames = [stereo_frame(k) for k in range(5)]
    frames[1] = dataclasses.replace(frames[1], left=np.zeros_like(frames[1].left), right=np.zeros_like(frames[1].left))
    # well-formed (decode accepts it) but too small to match: stereo_depth raises on it
    tiny = dataclasses.replace(frames[2].calib, width=4, height=4)
    frames[2] = dataclasses.replace(frames[2], left=frames[2].left[:4, :4].copy(), right=frames[2].right[:4, :4].copy(),
                                    calib=tiny)
    results: list[Obstacles] = []
    for frame in frames:  # lockstep, as camera_replay does: frame k+1 once frame k's obstacles are out
        camera.put(frame)
        results += collect(out, 1, 120, f"obstacles for frame {frame.frame_id}")
    assert [m.frame_id for m in results] == [0, 1, 2, 3, 4]
    for m in results:
        names = [t[0] for t in m.timing]
        assert names[0] == "camera_replay" and names[-2:] == ["voxel_mapper", "tracker"], names
        assert sorted(names[1:3]) == ["odometry", "stereo_depth"], names
        assert m.stamp_ns == 1_000_000_000 + m.frame_id * 100_000_000
        assert m.world_epoch >= started_ms  # a (re)started odometry anchors a world newer than any before
        assert all(a[1] <= b[1] for a, b in zip(m.timing, m.timing[1:], strict=False))
    cloud_sizes = {m.frame_id: len(m.points) for m in collect(clouds, 5, 30, "five clouds")}
    assert cloud_sizes[0] > 0 and cloud_sizes[1] == 0 and cloud_sizes[2] == 0, cloud_sizes  # blank; empty output
    reports = {s: last_health(health[s], lambda h: h.frames_out == 5, f"{s}'s Health to count five frames")
               for s in stages}
    assert reports["stereo_depth"].errors == 1 and "at least 8 px" in reports["stereo_depth"].detail["last_error"]
    assert reports["stereo_depth"].detail["degenerate"] >= 1
    assert reports["voxel_mapper"].errors == 0 and reports["tracker"].errors == 0
    assert all(r.dropped == 0 and r.decode_errors == 0 and r.p50_ms > 0 for r in reports.values()), reports
    wait_for(lambda: procs["tracker"].poll() is not None, 30, "the tracker to exit after --max-frames 5")
    for s, p in procs.items():
        assert processes.stop(p, signal.SIGTERM) == 0, processes.log(p)[-2000:]
        assert f"{s} ready" in processes.log(p) and f"{s} stopped: 5 frames out" in processes.log(p)


def last_health(sub: object, done: Callable[[Health], bool], what: str) -> Health:
    """The newest Health report once ``done`` holds for it."""
    box: list[Health] = []

    def check() -> bool:
        item = sub.recv(0.2)  # type: ignore[attr-defined]
        if item is not None:
            box[:] = [item.msg]
        return bool(box) and done(box[0])

    wait_for(check, 30, what)
    return box[0]


def test_run_and_topics_refuse_bad_arguments_with_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    from services.cli import main

    assert main(["run", "tracker", "--set", "tracker.no_such_key=1"]) == 2
    assert "unknown configuration key 'tracker.no_such_key'" in capsys.readouterr().err
    assert main(["topics", "echo"]) == 2
    assert "topics echo needs a KEY" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["run", "tracker", "--policy", "lifo"])
