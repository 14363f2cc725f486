"""``stereovox export foxglove RUN.mcap --out VIEW.mcap``: a recording Foxglove can open.

Stereovox recordings carry msgpack, which Foxglove does not decode; the export rewrites each
message as Foxglove's own protobuf schemas with the same conversion the live server uses
(``common.foxglove_convert``), at the capture time of the original, so the app's timeline, 3D
panel and image panel all line up.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from common.errors import InputError
from common.foxglove_convert import Channels, Converter
from common.messages import topic_of
from common.progress import progress
from common.recording import open_recording

FORMATS: tuple[str, ...] = ("foxglove",)
#: the topics the conversion draws; the rest (health, ground-truth disparity) is not decoded at all.
CONVERTED: tuple[str, ...] = (
    "camera/stereo", "stereo_depth/points", "stereo_depth/disparity", "odometry/ego",
    "voxel_mapper/clusters", "tracker/obstacles", "groundtruth/objects",
)


def export_foxglove(run: Path, out: Path) -> tuple[int, int]:
    """Write ``out`` from ``run``; returns (camera frames, Foxglove messages written)."""
    import foxglove

    reader = open_recording(run)
    total = reader.info().get("frames")
    if out.resolve() == run.resolve():
        raise InputError(f"export would overwrite its input {run}")
    out.parent.mkdir(parents=True, exist_ok=True)
    context = foxglove.Context()
    converter = Converter()
    frames = 0
    with foxglove.open_mcap(out, allow_overwrite=True, context=context):
        channels = Channels(context)
        stream = progress(
            reader.messages(topics=CONVERTED), total if isinstance(total, int) else None, "export",
            counts=lambda item: topic_of(item[0]) == "camera/stereo",
        )
        for key, msg in stream:
            topic = topic_of(key)
            frames += topic == "camera/stereo"
            channels.log(converter.convert(topic, msg), log_time_ns=msg.stamp_ns)
        channels.close()
    if reader.truncated is not None:
        print(f"export: {reader.truncated}", file=sys.stderr)
    return frames, channels.logged


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("format", choices=FORMATS, help="what to export to")
    parser.add_argument("run", type=Path, help="a stereovox recording (run.mcap from process or demo)")
    parser.add_argument("--out", type=Path, required=True, help="the file to write (overwritten)")


def run(args: argparse.Namespace) -> int:
    started = time.perf_counter()
    frames, written = export_foxglove(args.run, args.out)
    elapsed = time.perf_counter() - started
    per_frame = f", {1000 * elapsed / frames:.1f} ms per camera frame" if frames else ""
    print(f"export: {args.out} ({written} Foxglove messages, {frames} camera frames) in {elapsed:.1f} s{per_frame}")
    return 0
