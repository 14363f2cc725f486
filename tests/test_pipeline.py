"""End to end: `process` (one process, no bus) and `demo` (every stage its own process over Zenoh).

The two must give identical obstacles frame by frame on the same recording: lockstep replay and a
lossless wire make the distributed run as deterministic as the in-process one.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO, stereovox_cmd, wait_for

from common.codec import encode
from common.errors import ConfigError
from common.evaluation.evaluate import evaluate_recording
from common.messages import Obstacles
from common.recording import RecordingWriter, open_recording
from services.demo import BUNDLED
from services.pipeline import process_file

FRAMES = 30


def _obstacle_rows(msg: Obstacles) -> list[tuple]:
    return [
        (o.id, o.state, o.moving, o.age, *np.round(o.centroid, 9), *np.round(o.velocity, 9)) for o in msg.obstacles
    ]


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    assert BUNDLED.is_file(), f"bundled recording {BUNDLED} is missing"
    out = tmp_path_factory.mktemp("demo")
    proc = subprocess.run(
        [*stereovox_cmd("demo", "--max-frames", str(FRAMES), "--out", str(out), "--json")],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=400,
        start_new_session=True,
    )
    assert proc.returncode == 0, f"demo failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    return out / "run.mcap", report


@pytest.mark.timeout(450)
def test_demo_runs_every_stage_and_reports(demo_run: tuple[Path, dict]) -> None:
    run_path, report = demo_run
    assert report["frames"] == FRAMES
    for stage in ("stereo_depth", "odometry", "voxel_mapper", "tracker", "end_to_end"):
        assert report["latency_ms"][stage]["p50"] > 0, stage
    obstacles = open_recording(run_path).by_topic("tracker/obstacles")
    assert sorted(obstacles) == list(range(FRAMES)), "one Obstacles message per input frame"
    assert any(o.state == "tracked" for m in obstacles.values() for o in m.obstacles)
    assert report["odometry"] is not None and report["stereo"] is not None


@pytest.mark.timeout(450)
def test_process_and_demo_give_identical_obstacles(demo_run: tuple[Path, dict], tmp_path: Path) -> None:
    run_path, _ = demo_run
    local = tmp_path / "process.mcap"
    assert process_file(BUNDLED, local, max_frames=FRAMES, with_frames=False) == FRAMES
    distributed = open_recording(run_path).by_topic("tracker/obstacles")
    in_process = open_recording(local).by_topic("tracker/obstacles")
    assert sorted(distributed) == sorted(in_process)
    for frame_id in sorted(in_process):
        assert _obstacle_rows(distributed[frame_id]) == _obstacle_rows(in_process[frame_id]), frame_id


@pytest.mark.timeout(450)
def test_a_demo_run_restarted_at_the_mapper_gives_its_own_obstacles(
    demo_run: tuple[Path, dict], tmp_path: Path
) -> None:
    """The recorder wrote the bus in arrival order; joined again by frame id, the later stages agree."""
    run_path, _ = demo_run
    out = tmp_path / "again.mcap"
    assert process_file(run_path, out, resume_from="voxel_mapper") == FRAMES
    before, after = open_recording(run_path), open_recording(out)
    assert after.info()["processed_by"] == "stereovox process --from voxel_mapper"
    for topic in ("voxel_mapper/clusters", "tracker/obstacles"):
        assert sorted(after.by_topic(topic)) == list(range(FRAMES)), topic
    old, new = before.by_topic("tracker/obstacles"), after.by_topic("tracker/obstacles")
    for frame_id in range(FRAMES):
        assert _obstacle_rows(new[frame_id]) == _obstacle_rows(old[frame_id]), frame_id
    assert sorted(after.by_topic("groundtruth/objects")) == sorted(before.by_topic("groundtruth/objects"))
    figures = evaluate_recording(out)["latency_ms"]
    assert figures["end_to_end"] == {"p50": None, "p95": None}  # the mapper ran now, the stereo then
    assert figures["voxel_mapper"]["p50"] > 0.0 and figures["stereo_depth"]["p50"] > 0.0


@pytest.mark.timeout(450)
def test_a_run_restarted_at_the_tracker_copies_the_clusters_and_takes_new_settings(
    demo_run: tuple[Path, dict], tmp_path: Path
) -> None:
    run_path, _ = demo_run
    out = tmp_path / "patient.mcap"
    frames = 20
    sets = ["tracker.accept_frames=6"]
    assert process_file(run_path, out, resume_from="tracker", sets=sets, max_frames=frames) == frames
    before, after = open_recording(run_path), open_recording(out)
    assert after.config_dict()["tracker"]["accept_frames"] == 6
    assert before.config_dict()["tracker"]["accept_frames"] != 6
    clusters = after.by_topic("voxel_mapper/clusters")
    assert sorted(clusters) == list(range(frames)), "the clusters of the first 20 frames, and only those"
    recorded = before.by_topic("voxel_mapper/clusters")
    for frame_id, msg in clusters.items():
        assert encode(msg) == encode(recorded[frame_id]), frame_id

    def first_tracked(obstacles: dict[int, Obstacles]) -> int:
        return min(f for f, m in obstacles.items() if any(o.state == "tracked" for o in m.obstacles))

    assert first_tracked(before.by_topic("tracker/obstacles")) < 5
    assert first_tracked(after.by_topic("tracker/obstacles")) >= 5  # six frames of acceptance, counted from 0


@pytest.mark.timeout(300)
def test_a_run_made_by_another_version_restarts_with_the_settings_this_one_knows(
    demo_run: tuple[Path, dict], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    run_path, _ = demo_run
    reader = open_recording(run_path)
    stored = reader.config_dict()
    assert stored is not None
    stored["tracker"]["accept_frames"] = 6  # known: kept
    stored["tracker"]["retired_setting"] = 1.5  # a key a later version dropped
    stored["gone_section"] = {"x": 1}
    older = tmp_path / "older.mcap"
    with RecordingWriter(older) as writer:
        writer.describe(stored, reader.info())
        for key, msg in reader.messages():
            writer.write(key, msg)
    out = tmp_path / "again.mcap"
    with caplog.at_level("WARNING", logger="services.pipeline"):
        assert process_file(older, out, resume_from="tracker", max_frames=5) == 5
    left_out = caplog.text.split("left out: ")[1].split()
    assert sorted(name.rstrip(",") for name in left_out[:2]) == ["gone_section", "tracker.retired_setting"]
    restarted = open_recording(out).config_dict()
    assert restarted is not None and restarted["tracker"]["accept_frames"] == 6
    assert "retired_setting" not in restarted["tracker"]
    with pytest.raises(ConfigError, match=r"unknown configuration key 'tracker\.retired_setting'"):
        process_file(older, tmp_path / "typo.mcap", resume_from="tracker", sets=["tracker.retired_setting=2"])


def test_a_restart_names_what_the_recording_lacks(tmp_path: Path) -> None:
    out = tmp_path / "nothing.mcap"
    lacks = r"needs voxel_mapper/clusters, odometry/ego; .* has no voxel_mapper/clusters"
    with pytest.raises(ConfigError, match=lacks):
        process_file(BUNDLED, out, resume_from="tracker")
    assert not out.exists()


def _demo_until_alive(out: Path) -> tuple[subprocess.Popen[str], dict[str, int]]:
    """Start a demo and read its log until every service is alive; the pid of each service."""
    proc = subprocess.Popen(
        stereovox_cmd("demo", "--max-frames", str(FRAMES), "--out", str(out)),
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
    )
    pids: dict[str, int] = {}
    assert proc.stderr is not None
    for line in proc.stderr:
        match = re.search(r"(\w+)\s+started pid (\d+)", line)
        if match:
            pids[match.group(1)] = int(match.group(2))
        if "all services alive" in line:
            break
    return proc, pids


@pytest.mark.timeout(300)
def test_demo_names_a_stage_that_dies(tmp_path: Path) -> None:
    """SIGKILL the tracker mid-run: the demo stops every process and exits non-zero naming it."""
    proc, pids = _demo_until_alive(tmp_path)
    try:
        assert "tracker" in pids, f"no tracker started: {pids}"
        os.kill(pids["tracker"], signal.SIGKILL)
        _, err = proc.communicate(timeout=200)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
    assert proc.returncode == 1
    assert "stage tracker died" in err
    for name, pid in pids.items():
        assert not _alive(pid), f"{name} (pid {pid}) outlived the demo"


@pytest.mark.timeout(300)
def test_services_end_with_a_killed_demo(tmp_path: Path) -> None:
    """SIGKILL the demo itself (no chance to clean up): every service it started ends on its own."""
    proc, pids = _demo_until_alive(tmp_path)
    try:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
        wait_for(lambda: not any(_alive(pid) for pid in pids.values()), 30, "the services to follow their supervisor")
    finally:
        for pid in pids.values():  # only reached when the test failed: leave nothing behind
            with contextlib.suppress(ProcessLookupError):
                os.killpg(pid, signal.SIGKILL)
    assert {"router", "stereo_depth", "odometry", "voxel_mapper", "tracker", "recorder"} <= set(pids)
    assert open_recording(tmp_path / "run.mcap").info()  # the recorder stopped cleanly: its file reads


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as f:
        return f.read().split()[2] != "Z"


def test_demo_refuses_a_missing_recording(tmp_path: Path) -> None:
    proc = subprocess.run(
        stereovox_cmd("demo", "--out", str(tmp_path), "--recording", str(tmp_path / "nothing.mcap")),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert "nothing.mcap" in proc.stderr and "no such recording" in proc.stderr
