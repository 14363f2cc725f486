"""services/warmup.py: a stage's compiled code is loaded before it is alive, and nothing else changes."""

from __future__ import annotations

import json
import logging
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from common.config import Config
from services import warmup
from services.pipeline import process_file

REPO = Path(__file__).resolve().parents[1]
BUNDLED = REPO / "recordings" / "urban.mcap"

#: run in a fresh interpreter, where nothing compiled is loaded yet: warm a stage up, then put the
#: first real frames through it; prints how many kernel signatures the warm-up loaded, and which
#: kernels the real frames still had to load.
CHECK = """
import importlib, json, sys
from numba.core.registry import CPUDispatcher
from common.config import Config
from common.recording import open_recording
from services import warmup

name, run, bundled = sys.argv[1:4]
stage = importlib.import_module(f"services.{name}.service").stage(Config())

def signatures():
    found = {}
    for module_name, module in list(sys.modules.items()):
        if module_name.startswith(("services", "common")):
            for attr, value in list(vars(module).items()):
                if isinstance(value, CPUDispatcher):
                    found[f"{module_name}.{attr}"] = len(value.signatures)
    return found

cold = signatures()
stage.warm()
warm = signatures()
frames = {}
for topic in stage.inputs:
    source = bundled if topic == "camera/stereo" else run
    for _, msg in open_recording(source).messages(topics=[topic]):
        frames.setdefault(msg.frame_id, {})[topic] = warmup.off_the_wire(msg)
done = 0
for frame_id in sorted(frames)[:6]:  # the run's: the bundled recording's first frames
    got = frames[frame_id]
    if all(topic in got or topic in stage.optional for topic in stage.inputs):
        stage.process(*[got.get(topic) for topic in stage.inputs])
        done += 1
after = signatures()
print(json.dumps({
    "warmed": sum(warm.values()) - sum(cold.get(k, 0) for k in warm),
    "frames": done,
    "new": {k: [warm.get(k, 0), v] for k, v in after.items() if v != warm.get(k, 0)},
}))
"""


@pytest.fixture(scope="module")
def real_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Every stage's output for the bundled recording's first frames, as `stereovox process` writes them."""
    run = tmp_path_factory.mktemp("warm") / "run.mcap"
    process_file(BUNDLED, run, max_frames=6, with_frames=False)
    return run


@pytest.mark.timeout(300)
@pytest.mark.parametrize("name", ["voxel_mapper", "tracker"])
def test_after_the_warm_up_the_first_real_frames_load_no_compiled_code(name: str, real_run: Path) -> None:
    """The two stages with numba kernels of their own (stereo and odometry call OpenCV: below)."""
    done = subprocess.run(
        [sys.executable, "-c", CHECK, name, str(real_run), str(BUNDLED)],
        capture_output=True, text=True, cwd=REPO, timeout=240, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(done.stdout.splitlines()[-1])
    assert report["frames"] == 6
    assert report["warmed"] > 10
    assert report["new"] == {}, f"{name}: kernels the made-up frames never called: {report['new']}"


def test_the_made_up_frames_go_all_the_way_through_every_core(caplog: pytest.LogCaptureFixture) -> None:
    """Matched, followed, mapped and tracked as real ones are: a warm-up that stops early loads little."""
    from services.odometry import StereoOdometry
    from services.odometry.service import stage as odometry_stage
    from services.stereo_depth import StereoDepth
    from services.stereo_depth.service import stage as stereo_stage
    from services.tracker import Tracker
    from services.tracker.service import stage as tracker_stage
    from services.tracker.service import warm_frames
    from services.voxel_mapper import VoxelMapper
    from services.voxel_mapper.service import stage as mapper_stage

    cfg = Config()
    stereo, odometry = StereoDepth.from_config(cfg), StereoOdometry.from_config(cfg, initial_epoch=1)
    for frame in warmup.stereo_frames():
        cloud, _ = stereo.process(frame)
        ego = odometry.process(frame, None)
        assert len(cloud.points) > 10_000 and len(cloud.keypoint_ids) > 1_000
        assert ego.valid and (frame.frame_id == 0 or ego.inliers > 100)
    mapper = VoxelMapper.from_config(cfg)
    clusters = [mapper.process(c, e) for c, e in warmup.clouds_and_motions()]
    assert [len(c.clusters) for c in clusters] == [4, 4, 4, 3, 3, 3]  # the last box gone after frame 2
    tracker = Tracker.from_config(cfg)
    obstacles = [tracker.process(c, e) for c, e in warm_frames()]
    assert sum(o.state == "tracked" for o in obstacles[-1].obstacles) >= 8
    with caplog.at_level(logging.INFO, logger="services.warmup"):
        for stage in (stereo_stage(cfg), odometry_stage(cfg), mapper_stage(cfg), tracker_stage(cfg)):
            stage.warm()
    assert "warm-up failed" not in caplog.text
    assert caplog.text.count("warmed in") == 4


def obstacles_and_clusters(warm: bool, real_run: Path) -> list[tuple[object, ...]]:
    """The voxel mapper's and the tracker's stages over the run's inputs, warmed up first or not."""
    from common.recording import open_recording
    from services.tracker.service import stage as tracker_stage
    from services.voxel_mapper.service import stage as mapper_stage

    mapper, tracker = mapper_stage(Config()), tracker_stage(Config())
    if warm:
        mapper.warm()
        tracker.warm()
    inputs: dict[int, dict[str, object]] = {}
    for _, msg in open_recording(real_run).messages(topics=["stereo_depth/points", "odometry/ego"]):
        inputs.setdefault(msg.frame_id, {})[type(msg).__name__] = warmup.off_the_wire(msg)
    out = []
    for frame_id in sorted(inputs):
        cloud, ego = inputs[frame_id]["PointCloud"], inputs[frame_id]["EgoMotion"]
        (clusters,) = mapper.process(cloud, ego)
        (obstacles,) = tracker.process(warmup.off_the_wire(clusters), ego)
        out.append(tuple(c.centroid.tolist() for c in clusters.clusters))
        out.append(tuple((o.id, o.state, o.moving, *np.round(o.velocity, 12).tolist()) for o in obstacles.obstacles))
    return out


def test_the_warm_up_leaves_the_stages_own_cores_as_they_were(real_run: Path) -> None:
    """It runs a second instance of each core: the service's own starts clean (ids from 1, no tracks)."""
    cold, warmed = obstacles_and_clusters(False, real_run), obstacles_and_clusters(True, real_run)
    assert cold == warmed
    assert any(len(frame) > 0 for frame in cold[1::2])  # there are obstacles to compare


def test_a_failing_warm_up_is_logged_and_the_service_starts(caplog: pytest.LogCaptureFixture) -> None:
    """Whether the core fails on a frame or the frames cannot be made."""

    def broken(frame: object) -> None:
        raise RuntimeError("no such kernel")

    def no_frames() -> list[tuple[object]]:
        raise ValueError("no rig")

    with caplog.at_level(logging.INFO, logger="services.warmup"):
        assert warmup.warm("odometry", lambda: broken, warmup.stereo_inputs) >= 0.0
        assert warmup.warm("tracker", lambda: broken, no_frames) >= 0.0
    assert "odometry: warm-up failed" in caplog.text and "no such kernel" in caplog.text
    assert "tracker: warm-up failed" in caplog.text and "no rig" in caplog.text


def test_the_made_up_frames_are_what_a_subscriber_gets() -> None:
    """Read-only arrays, as decoded off the bus: numba compiles for them apart from writable ones."""
    frame = warmup.stereo_frames(1)[0]
    cloud, ego = warmup.clouds_and_motions(1)[0]
    assert not frame.left.flags.writeable and not cloud.points.flags.writeable and not ego.pose.flags.writeable
    assert frame.left.shape == (warmup.HEIGHT, warmup.WIDTH, 3) and frame.calib.width == warmup.WIDTH
