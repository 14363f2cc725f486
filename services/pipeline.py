"""Every stage's core chained in one process, no bus: ``stereovox process IN.mcap --out OUT.mcap``.

This is the deterministic run that evaluation, tests and benchmarks use; the distributed run over
Zenoh must give the same obstacles from the same recording. The output holds every stage's
messages, the input's ground truth and camera frames, and the effective configuration.

``--from voxel_mapper`` or ``--from tracker`` restarts a finished run (made by ``process`` or
recorded from the bus) at that stage: its recorded inputs are fed to the later stages again and
everything else is copied, as a ROS user replays a bag's point clouds into a tracker node. Stereo
and odometry take most of a frame's time, so tuning the mapper or tracker this way costs seconds
per run instead of minutes. The run's own stored configuration is the base, so with no ``--set``
the run is reproduced exactly.
"""

from __future__ import annotations

import argparse
import logging
from collections import defaultdict
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

from common.config import Config
from common.config_loading import load_config, recording_overrides
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
from common.recording import RecordingReader, RecordingWriter, open_recording, peek_stamp
from services.odometry import StereoOdometry
from services.stereo_depth import StereoDepth
from services.tracker import Tracker
from services.voxel_mapper import VoxelMapper

log = logging.getLogger(__name__)

#: stages a finished run can be restarted at (``--from``), in pipeline order, with the recorded
#: topics each needs of one frame, and what each stage publishes (made anew, not copied).
RESUMABLE: dict[str, tuple[str, ...]] = {
    "voxel_mapper": ("stereo_depth/points", "odometry/ego"),
    "tracker": ("voxel_mapper/clusters", "odometry/ego"),
}
PRODUCES: dict[str, str] = {"voxel_mapper": "voxel_mapper/clusters", "tracker": "tracker/obstacles"}


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


def config_for(
    reader: RecordingReader, file: str | None = None, sets: list[str] | None = None, stored: bool = False
) -> Config:
    """Defaults, then what the recording says of itself, then file and --set.

    ``stored``: start from the configuration that made the recording, where it holds one (a run
    restarted at a later stage must keep what its earlier stages were made with).
    """
    base = reader.config_dict() if stored else None
    unknown: list[str] = []
    cfg = load_config(file, sets or [], base=base or recording_overrides(reader.info()), base_unknown=unknown)
    if unknown:
        log.warning("%s was made with settings this version does not have, left out: %s", reader.path,
                    ", ".join(unknown))
    return cfg


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


def _last_frame(reader: RecordingReader, topic: str, max_frames: int | None) -> tuple[int | None, int]:
    """The id of the ``max_frames``-th frame of ``topic`` (None: no limit) and the frames it has."""
    ids = sorted({stamp[0] for rec in reader.raw() if topic_of(rec.key) == topic and (stamp := peek_stamp(rec.data))})
    if max_frames is None or max_frames >= len(ids):
        return None, len(ids)
    return ids[max_frames - 1], max_frames


def _resume_inputs(reader: RecordingReader, stage: str) -> tuple[str, ...]:
    """The recorded topics ``stage`` needs; a clear error when it is no stage to restart at or one is absent."""
    if stage not in RESUMABLE:
        raise ConfigError(f"--from {stage!r}: a run restarts at one of {', '.join(RESUMABLE)}")
    needs = RESUMABLE[stage]
    missing = [topic for topic in needs if not reader.has_topic(topic)]
    if missing:
        raise ConfigError(f"--from {stage} needs {', '.join(needs)}; {reader.path} has no {', '.join(missing)}")
    return needs


def resume_recording(
    reader: RecordingReader, cfg: Config, stage: str, last: int | None = None
) -> Iterator[tuple[str, Message, bool]]:
    """Yield ``(key, message, made)``: the run's messages copied, and ``stage`` onwards made again.

    A frame goes through once every topic ``stage`` needs has arrived with its id, whatever the
    order the recorder wrote them in; one that never completes (a message lost on the bus) is
    skipped and named in the log. The new outputs take the key of the input they came from, so a
    run recorded under another vehicle name stays under it. ``last``: no message of a later frame.
    """
    needs = _resume_inputs(reader, stage)
    later = list(RESUMABLE)[list(RESUMABLE).index(stage) :]
    remade = {PRODUCES[s] for s in later}
    mapper = VoxelMapper.from_config(cfg) if "voxel_mapper" in later else None
    tracker = Tracker.from_config(cfg)
    pending: dict[int, dict[str, tuple[str, Message]]] = defaultdict(dict)
    for key, msg in reader.messages():
        topic = topic_of(key)
        if topic in remade or (last is not None and msg.frame_id > last):
            continue
        yield key, msg, False
        if topic not in needs:
            continue
        got = pending[msg.frame_id]
        got[topic] = (key, msg)
        if len(got) < len(needs):
            continue
        del pending[msg.frame_id]
        vehicle_key = got[needs[0]][0]
        ego = got["odometry/ego"][1]
        assert isinstance(ego, EgoMotion)
        if mapper is not None:
            cloud = got["stereo_depth/points"][1]
            assert isinstance(cloud, PointCloud)
            start = now_ns()
            clusters = stamp_output(mapper.process(cloud, ego), [cloud, ego], "voxel_mapper", start)
            yield _sibling(vehicle_key, "voxel_mapper/clusters"), clusters, True
        else:
            clusters = got["voxel_mapper/clusters"][1]
            assert isinstance(clusters, Clusters)
        start = now_ns()
        obstacles = stamp_output(tracker.process(clusters, ego), [clusters, ego], "tracker", start)
        yield _sibling(vehicle_key, "tracker/obstacles"), obstacles, True
    if pending:
        log.warning("%d frames lacked one of %s and were skipped: %s", len(pending), ", ".join(needs), sorted(pending))


def _sibling(key: str, topic: str) -> str:
    """``topic`` on the vehicle of ``key`` (``stereovox/<vehicle>/...``)."""
    parts = key.split("/", 2)
    return key_for(topic, parts[1]) if len(parts) == 3 and parts[0] == "stereovox" else key_for(topic)


def process_file(
    src: Path,
    out: Path,
    cfg: Config | None = None,
    max_frames: int | None = None,
    with_frames: bool = True,
    config_file: str | None = None,
    sets: list[str] | None = None,
    resume_from: str | None = None,
) -> int:
    """Run the pipeline over ``src`` into ``out``; returns the number of stereo frames processed.

    With ``resume_from`` (a stage of :data:`RESUMABLE`), ``src`` is a finished run restarted at
    that stage (:func:`resume_recording`).
    """
    reader = open_recording(src)
    cfg = cfg or config_for(reader, config_file, sets, stored=resume_from is not None)
    if resume_from is not None:
        return _resume_file(reader, out, cfg, resume_from, max_frames, with_frames)
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


def _resume_file(
    reader: RecordingReader, out: Path, cfg: Config, stage: str, max_frames: int | None, with_frames: bool
) -> int:
    last, total = _last_frame(reader, _resume_inputs(reader, stage)[0], max_frames)
    processed = 0
    with RecordingWriter(out, compression=cfg.recorder.compression, atomic=True) as writer:
        writer.describe(cfg.to_dict(), {**reader.info(), "processed_by": f"stereovox process --from {stage}"})
        items = resume_recording(reader, cfg, stage, last)
        for key, msg, made in progress(
            items, total, f"{stage}+ {reader.path.name}", counts=lambda item: item[2] and isinstance(item[1], Obstacles)
        ):
            if made and isinstance(msg, Obstacles):
                processed += 1
            if with_frames or not isinstance(msg, StereoFrame):
                writer.write(key, msg)
    if reader.truncated is not None:
        log.warning("%s", reader.truncated)
    return processed


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "recording", type=Path, help="input recording (camera frames, ground truth), or a finished run with --from"
    )
    parser.add_argument("--out", type=Path, required=True, help="output recording")
    parser.add_argument("--max-frames", type=int, default=None)
    parser.add_argument("--config", default=None, help="configuration file (TOML/YAML)")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--no-frames", action="store_true", help="leave the camera frames out of OUT")
    parser.add_argument(
        "--from",
        dest="resume_from",
        choices=list(RESUMABLE),
        help="restart a finished run at this stage: its recorded inputs through the later stages, the rest copied "
        "(base configuration: the run's own)",
    )


def run(args: argparse.Namespace) -> int:
    n = process_file(
        args.recording,
        args.out,
        max_frames=args.max_frames,
        with_frames=not args.no_frames,
        config_file=args.config,
        sets=args.sets,
        resume_from=args.resume_from,
    )
    print(f"processed {n} frames -> {args.out}")
    return 0
