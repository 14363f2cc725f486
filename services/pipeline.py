"""Every stage's core chained in one process, no bus: ``stereovox process IN.mcap --out OUT.mcap``.

This is the deterministic run that evaluation, tests and benchmarks use; the distributed run over
Zenoh must give the same obstacles from the same recording. The output holds every stage's
messages, the input's ground truth and camera frames, and the effective configuration.
"""

from __future__ import annotations

import argparse
import logging
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

from common.config import Config, load_config, recording_overrides
from common.errors import ConfigError
from common.messages import (
    Clusters,
    Disparity,
    EgoMotion,
    Message,
    Obstacles,
    PointCloud,
    StereoFrame,
    VehicleMotion,
    key_for,
    now_ns,
    stamp_output,
    topic_of,
)
from common.progress import progress
from common.recording import RecordingReader, RecordingWriter, open_recording
from services.odometry import StereoOdometry
from services.stereo_depth import StereoDepth
from services.tracker import Tracker
from services.voxel_mapper import VoxelMapper

log = logging.getLogger(__name__)


@dataclass
class FrameResult:
    """Everything the stages made of one stereo frame."""

    frame: StereoFrame
    cloud: PointCloud
    disparity: Disparity
    ego: EgoMotion
    clusters: Clusters
    obstacles: Obstacles
    stage_ms: dict[str, float] = field(default_factory=dict)

    def outputs(self) -> dict[str, Message]:
        return {
            "stereo_depth/points": self.cloud,
            "stereo_depth/disparity": self.disparity,
            "odometry/ego": self.ego,
            "voxel_mapper/clusters": self.clusters,
            "tracker/obstacles": self.obstacles,
        }


class Pipeline:
    """The paper's five steps, one call each, with the timing trail the bus shells would add."""

    def __init__(self, cfg: Config) -> None:
        self.cfg = cfg
        self.stereo = StereoDepth.from_config(cfg)
        self.odometry = StereoOdometry.from_config(cfg)
        self.mapper = VoxelMapper.from_config(cfg)
        self.tracker = Tracker.from_config(cfg)

    def process(self, frame: StereoFrame, vehicle: VehicleMotion | None = None) -> FrameResult:
        t = now_ns()
        frame = replace(frame, timing=[("camera_replay", t, t)])
        times: dict[str, float] = {}

        start = now_ns()
        cloud, disparity = self.stereo.process(frame)
        stamp_output(cloud, [frame], "stereo_depth", start)
        stamp_output(disparity, [frame], "stereo_depth", start)
        times["stereo_depth"] = (now_ns() - start) / 1e6

        start = now_ns()
        ego = stamp_output(self.odometry.process(frame, vehicle), [frame], "odometry", start)
        times["odometry"] = (now_ns() - start) / 1e6

        start = now_ns()
        clusters = stamp_output(self.mapper.process(cloud, ego), [cloud, ego], "voxel_mapper", start)
        times["voxel_mapper"] = (now_ns() - start) / 1e6

        start = now_ns()
        obstacles = stamp_output(self.tracker.process(clusters, ego), [clusters, ego], "tracker", start)
        times["tracker"] = (now_ns() - start) / 1e6
        return FrameResult(frame, cloud, disparity, ego, clusters, obstacles, times)


def config_for(reader: RecordingReader, file: str | None = None, sets: list[str] | None = None) -> Config:
    """Defaults, then what the recording says of itself, then file and --set."""
    return load_config(file, sets or [], base=recording_overrides(reader.info()))


def run_recording(
    reader: RecordingReader, cfg: Config, max_frames: int | None = None
) -> Iterator[tuple[str, Message] | FrameResult]:
    """Yield the recording's ground truth and sensor inputs untouched and a FrameResult for every stereo frame.

    With ``odometry.fuse_ins`` each frame goes to the odometry with the ``vehicle/motion`` sample of
    the same frame id, wherever it lies in the file (the bus joins them by id too); the samples are
    read first, and a recording without any is refused.
    """
    sensors: dict[int, VehicleMotion] = {}
    if cfg.odometry.fuse_ins:
        sensors = {m.frame_id: m for _, m in reader.messages(topics=["vehicle/motion"])}
        if not sensors:
            raise ConfigError(f"odometry.fuse_ins needs vehicle/motion (INS) messages; {reader.path} has none")
    pipeline = Pipeline(cfg)
    frames = 0
    for key, msg in reader.messages():
        topic = topic_of(key)
        if isinstance(msg, StereoFrame):
            if max_frames is not None and frames >= max_frames:
                break
            frames += 1
            yield pipeline.process(msg, sensors.get(msg.frame_id))
        elif _passed_through(topic, frames, max_frames):
            yield key, msg


def _passed_through(topic: str, frames: int, max_frames: int | None) -> bool:
    """Sensor samples come before their frame, ground truth after it: each is kept while its frame is."""
    if topic == "vehicle/motion":
        return max_frames is None or frames < max_frames
    return topic.startswith("groundtruth/") and (max_frames is None or frames <= max_frames)


def process_file(
    src: Path,
    out: Path,
    cfg: Config | None = None,
    max_frames: int | None = None,
    with_frames: bool = True,
    config_file: str | None = None,
    sets: list[str] | None = None,
) -> int:
    """Run the pipeline over ``src`` into ``out``; returns the number of stereo frames processed."""
    reader = open_recording(src)
    cfg = cfg or config_for(reader, config_file, sets)
    info = reader.info()
    total = info.get("frames") if isinstance(info.get("frames"), int) else None
    if max_frames is not None:
        total = min(total or max_frames, max_frames)
    vehicle = cfg.bus.vehicle
    processed = 0
    with RecordingWriter(out, compression=cfg.recorder.compression, atomic=True) as writer:
        writer.describe(cfg.to_dict(), {**info, "processed_by": "stereovox process"})
        for item in progress(
            run_recording(reader, cfg, max_frames),
            total,
            f"process {src.name}",
            counts=lambda item: isinstance(item, FrameResult),
        ):
            if isinstance(item, FrameResult):
                processed += 1
                if with_frames:
                    frame = replace(item.frame, image_format="jpeg")
                    writer.write(key_for("camera/stereo", vehicle), frame)
                for topic, msg in item.outputs().items():
                    writer.write(key_for(topic, vehicle), msg)
            else:
                writer.write(item[0], item[1])
    if reader.truncated is not None:
        log.warning("%s", reader.truncated)
    return processed


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", type=Path, help="input recording (camera frames, ground truth)")
    parser.add_argument("--out", type=Path, required=True, help="output recording")
    parser.add_argument("--max-frames", type=int, default=None)
    parser.add_argument("--config", default=None, help="configuration file (TOML/YAML)")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--no-frames", action="store_true", help="leave the camera frames out of OUT")


def run(args: argparse.Namespace) -> int:
    n = process_file(
        args.recording,
        args.out,
        max_frames=args.max_frames,
        with_frames=not args.no_frames,
        config_file=args.config,
        sets=args.sets,
    )
    print(f"processed {n} frames -> {args.out}")
    return 0
